//! Content checksums of step records, so both ends can prove every step arrived exactly once.
//!
//! The checksum of an episode is the wrapping sum of its records' checksums: independent of
//! arrival order, and a lost or duplicated record changes it.

use crate::validate::StepView;

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(FNV_PRIME);
    }
    h
}

fn fnv_floats(h: u64, values: &[f32]) -> u64 {
    values.iter().fold(h, |h, v| fnv(h, &v.to_bits().to_le_bytes()))
}

/// FNV-1a (64-bit) over every field of the record: ids, index, version, the float bits of
/// obs, action, reward and final obs, and the end flags.
pub fn step_checksum(step: &StepView<'_>) -> u64 {
    let mut h = fnv(FNV_OFFSET, &step.episode_id.to_le_bytes());
    h = fnv(h, &step.step_index.to_le_bytes());
    h = fnv(h, &step.policy_version.to_le_bytes());
    h = fnv_floats(h, step.obs);
    h = fnv_floats(h, step.action);
    h = fnv_floats(h, &[step.reward]);
    h = fnv(h, &[u8::from(step.terminal), u8::from(step.truncated)]);
    fnv_floats(h, step.final_obs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_changes_the_checksum() {
        let obs = [0.5f32, -0.25];
        let base = StepView {
            episode_id: 3,
            step_index: 1,
            policy_version: 2,
            obs: &obs,
            action: &[0.1],
            reward: -0.5,
            terminal: false,
            truncated: false,
            final_obs: &[],
        };
        let c = step_checksum(&base);
        let variants = [
            StepView {
                episode_id: 4,
                ..base
            },
            StepView {
                step_index: 2,
                ..base
            },
            StepView {
                policy_version: 3,
                ..base
            },
            StepView {
                obs: &[0.5, -0.26],
                ..base
            },
            StepView {
                action: &[0.2],
                ..base
            },
            StepView { reward: -0.4, ..base },
            StepView {
                terminal: true,
                ..base
            },
            StepView {
                truncated: true,
                final_obs: &obs,
                ..base
            },
        ];
        for v in &variants {
            assert_ne!(step_checksum(v), c, "{v:?}");
        }
        assert_eq!(step_checksum(&base), c);
    }
}
