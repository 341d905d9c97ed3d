//! Helpers shared by the unit tests.

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::Tensor;

use crate::config::Td3Config;

/// Every float parameter of a module, in visiting order.
pub(crate) fn params<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().try_into_vec::<f32>().unwrap());
        }
    }
    let mut c = Collect(Vec::new());
    module.visit(&mut c);
    c.0
}

/// Small networks on a 3-D observation and a 1-D action, fast enough for many updates.
pub(crate) fn tiny_config() -> Td3Config {
    Td3Config {
        obs_dim: 3,
        act_dim: 1,
        laser_dim: 0,
        actor_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        batch_size: 64,
        replay_capacity: 8192,
        actor_warmup_updates: 0,
        seed: 7,
        ..Td3Config::default()
    }
}

pub(crate) use crate::batch::random_batch;

/// A fresh, empty directory under the system temp dir, unique per test and process.
pub(crate) use testkit::fresh_dir as temp_dir;
