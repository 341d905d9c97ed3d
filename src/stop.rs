//! `adp stop`: ends a running learner cleanly (final checkpoint, then export by `adp train`)
//! through its `Shutdown` call, with the operator credential of its run directory. Actors hold
//! only the run token, which `Shutdown` refuses.

use std::path::PathBuf;

use anyhow::Context;
use learner_service::{read_status, OPERATOR_TOKEN_FILE, SOCKET_FILE};
use proto::auth::{read_token_file, OPERATOR_METADATA};
use proto::grpc::LearnerAddress;
use proto::pb;

/// `adp stop`.
#[derive(clap::Args, Debug)]
pub struct StopArgs {
    /// The run directory of the learner to stop (on the learner's host: the call goes through
    /// its Unix socket).
    #[arg(long)]
    pub run_dir: PathBuf,
    /// Stop without a final checkpoint.
    #[arg(long)]
    pub no_checkpoint: bool,
}

/// `adp stop`: asks the learner of `run_dir` to stop and returns once it has accepted.
pub fn command(a: &StopArgs) -> anyhow::Result<()> {
    let dir = &a.run_dir;
    let status = read_status(dir).context("is a learner running in this directory?")?;
    let socket = dir.join(SOCKET_FILE);
    anyhow::ensure!(
        socket.exists(),
        "{} does not exist: run `adp stop` on the learner's host while it runs",
        socket.display()
    );
    let token = read_token_file(&dir.join("token"))?;
    let operator = read_token_file(&dir.join(OPERATOR_TOKEN_FILE))?;
    let address = LearnerAddress {
        addr: format!("unix:{}", socket.display()),
        token: Some(token),
        tls: None,
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the tokio runtime")?;
    runtime.block_on(async {
        let (mut control, _) = address
            .connect()
            .await
            .with_context(|| format!("cannot reach the learner at {}", socket.display()))?;
        let mut request = tonic::Request::new(pb::ShutdownRequest {
            run: Some(pb::RunRef {
                run_id: status.run_id.clone(),
                incarnation: status.incarnation,
            }),
            checkpoint: !a.no_checkpoint,
        });
        request.metadata_mut().insert(
            OPERATOR_METADATA,
            operator
                .parse()
                .context("the operator token is not a valid header value")?,
        );
        control
            .shutdown(request)
            .await
            .map_err(|s| anyhow::anyhow!("the learner refused to stop: {}", s.message()))?;
        anyhow::Ok(())
    })?;
    println!(
        "learner of run {} is stopping{}",
        status.run_id,
        if a.no_checkpoint {
            ""
        } else {
            " after a final checkpoint"
        }
    );
    Ok(())
}
