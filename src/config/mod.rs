//! The configuration files the commands read (a training run's [`TrainConfig`], from the
//! `train_config` library; the evaluation's [`EvalConfig`], from `eval`) and the one-line
//! error helper every command uses.

pub use train_config::TrainConfig;

pub use eval::config::{one_line, EvalConfig, UnknownName};

/// `e` and its causes on one line, `outer: inner: ...` like anyhow's `{:#}`, leaving out a cause
/// whose message the text already ends with (the component errors include their source in
/// their own message).
pub fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.is_empty() {
            line = text;
        } else if !line.ends_with(&text) {
            line = format!("{line}: {text}");
        }
    }
    one_line(&line)
}
