//! An arm of an experiment (a planner, an action space, a speed cap, training worlds, an
//! observation layout, a start) and the names it is written with.

use serde::{Deserialize, Serialize};

use actor::LaserLayout;
use planner::{ActionSpace, PlannerKind};

/// What an arm's training starts from (`start` of `[experiment]` or of a group).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Start {
    /// The training configuration's own start: the actor fitted to DDP (`[train.service]
    /// ddp_init`), or to `[train.service] init_action` when given. The paper's start, and
    /// the one every stage stored before this key existed was trained from.
    #[default]
    Ddp,
    /// The actor fitted to the arm's best constant action from its constant search (on
    /// `[constant_search] worlds`, never a test world), as `[service] init_action` (in place
    /// of any `[train.service] init_action`). The arm's id ends in `-bestconst`, its untrained
    /// control is that fitted actor, and its trainings' recipes name the search's key.
    BestConstant,
}

impl Start {
    /// Whether this is the default start ([`Start::Ddp`]), which recipes and ids leave out.
    pub fn is_ddp(&self) -> bool {
        *self == Start::Ddp
    }
}

/// One arm: a planner, an action space, a speed cap, a set of training worlds and an
/// observation layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Arm {
    /// The planner.
    pub planner: PlannerKind,
    /// The ADP action space.
    pub space: ActionSpace,
    /// Speed cap (m/s).
    pub speed: f64,
    /// Training-world selection as written.
    pub train_worlds: String,
    /// The observation layout when it is not `[train.env] observation` (`None`: that one).
    pub observation: Option<LaserLayout>,
    /// What its training starts from.
    pub start: Start,
    /// The training recipe of its group (`None`: the experiment's `[train]`).
    pub recipe: Option<String>,
}

impl Arm {
    /// A file-name-safe id, e.g. `dwa-decremental-1.5-train`, with an observation layout
    /// of its own `dwa-decremental-1.5-train-sectors15`, and starting from the best constant
    /// `dwa-decremental-1.5-train-bestconst`, and of a group's recipe `project` in
    /// `dwa-decremental-1.5-train-bestconst-project`. Only letters, digits and `-+._`: a
    /// space's `:` becomes `_` (`dwa-weights_dwa-1.5-fit`), since the ids name directories of
    /// experiments kept in the repository, and Windows checkouts refuse `:` in a path.
    pub fn id(&self) -> String {
        let worlds: String = self
            .train_worlds
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let layout: String = self.observation.map_or_else(String::new, |l| {
            let name: String = l
                .to_string()
                .chars()
                .filter(char::is_ascii_alphanumeric)
                .collect();
            format!("-{name}")
        });
        let start = match self.start {
            Start::Ddp => "",
            Start::BestConstant => "-bestconst",
        };
        let recipe = self.recipe.as_ref().map_or_else(String::new, |r| format!("-{r}"));
        format!(
            "{}-{}-{}-{worlds}{layout}{start}{recipe}",
            planner_name(self.planner),
            space_label(self.space).replace(':', "_"),
            speed_label(self.speed)
        )
    }

    /// Whether `other` differs from this arm at most in its observation layout and training
    /// worlds, so that its DDP, constant search and best constant are this arm's: they observe
    /// nothing and are searched on `[constant_search] worlds`, one selection for every arm.
    pub fn same_controls(&self, other: &Arm) -> bool {
        (self.planner, self.space) == (other.planner, other.space) && self.speed == other.speed
    }

    /// Whether `other` differs from this arm at most in its training worlds, so that its
    /// untrained policy (the initialized actor of the first seed, which has seen no world) is
    /// this arm's.
    pub fn same_untrained(&self, other: &Arm) -> bool {
        self.same_controls(other)
            && self.observation == other.observation
            && self.start == other.start
            && self.recipe == other.recipe
    }
}

/// The planner's name as on the command line (`log-mppi`).
pub fn planner_name(p: PlannerKind) -> String {
    p.name().to_string()
}

/// The action space's name (`decremental`).
pub fn space_label(s: ActionSpace) -> String {
    learner::export::space_name(s)
}

/// A speed as in file names and tables (`1.5`, `2.0`).
pub fn speed_label(v: f64) -> String {
    format!("{v:.1}")
}
