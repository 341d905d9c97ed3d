//! What enters the replay buffer: steps from either data plane and episode reports, each
//! validated, checked against its lease and its episode's order, and counted.
//!
//! A step is admitted only from the lease's actor (with its credential), under a valid lease,
//! in order within its episode, made with a published policy version and within the episode
//! cap; any other step is refused, and a refused step of a lease's own actor breaks the lease
//! (its episode can never complete). A step the learner stored already (a batch resent over a
//! broken connection: same actor, lease, episode and step index) is recognised, counted and
//! acknowledged as a duplicate without being stored again, even after its lease ended. A
//! report is checked the same way, then verified against the steps received, and ends the
//! lease once every episode of it is complete.

use std::time::Duration;

use learner::replay::{Step, StepEnd};
use proto::checksum::step_checksum;
use proto::plane::LeaseHeader;
use proto::validate::Refusal;
use proto::{pb, StepView};
use scheduler::RegistryError;

use crate::shared::Shared;
use crate::state::Core;
use crate::totals::EpisodeStat;

/// The data plane a step record arrived on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// The shared-memory step service (actors on the learner's host).
    Shm,
    /// The gRPC `Data` service.
    Grpc,
}

/// What became of a step that was not refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stored {
    /// Stored in the replay buffer.
    Inserted,
    /// Stored earlier (the step arrived again); not stored twice.
    Duplicate,
}

/// The refusal of a step or report that arrives once the run is over (the final checkpoint is
/// being written without it).
fn run_over(lease: u64) -> Refusal {
    Refusal::Lease(
        lease,
        "the run is over: the learner is writing its final checkpoint".into(),
    )
}

/// The refusal of a request whose lease the registry does not accept.
fn lease_refusal(e: RegistryError) -> Refusal {
    match e {
        RegistryError::UnknownActor { actor } => Refusal::UnknownActor(actor, "not registered".into()),
        RegistryError::RetiredActor { actor } => {
            Refusal::UnknownActor(actor, "retired (its rank registered again)".into())
        }
        RegistryError::UnknownLease { lease, .. }
        | RegistryError::ExpiredLease { lease, .. }
        | RegistryError::LeaseOfOtherActor { lease, .. }
        | RegistryError::AlreadyFinished { lease, .. }
        | RegistryError::EpisodeOverflow { lease, .. } => Refusal::Lease(lease, e.to_string()),
        other => Refusal::Lease(0, other.to_string()),
    }
}

impl Shared {
    /// Validates one step that arrived on `plane` and stores it, blocking while the rate
    /// limiter holds inserts back, unless it was stored before ([`Stored::Duplicate`]).
    /// Returns the refusal when the step was refused (counted and logged).
    pub fn ingest(&self, plane: Plane, header: &LeaseHeader, step: &StepView<'_>) -> Result<Stored, Refusal> {
        let result = self.ingest_inner(plane, header, step);
        if let Err(why) = &result {
            let _actor =
                tracing::info_span!("actor", actor_id = header.actor_id, lease = header.lease_id).entered();
            self.refuse(why, 1);
        }
        result
    }

    fn ingest_inner(
        &self,
        plane: Plane,
        header: &LeaseHeader,
        step: &StepView<'_>,
    ) -> Result<Stored, Refusal> {
        if header.incarnation != self.validator.incarnation {
            return Err(Refusal::StaleIncarnation {
                current: self.validator.incarnation,
                got: header.incarnation,
            });
        }
        if let Err(why) = self.validator.check_step(step) {
            // The episode can never complete: end its lease (the actor is told), unless the
            // sender is not the lease's actor.
            let now = self.now_ms();
            self.lock().break_lease(header, &why, now);
            return Err(why);
        }
        let mut core = self.lock();
        core.check_secret(header.actor_id, &header.secret)?;
        // A resent step is recognised before its lease is looked at: the lease may have ended
        // since the step was first stored.
        if core.take_duplicate(header, step) {
            return Ok(Stored::Duplicate);
        }
        if core.closed {
            return Err(run_over(header.lease_id));
        }
        // Hold inserts back while the learner lags, but only while an update can run: with
        // nothing ready to sample no update can make room, and waiting would deadlock.
        while core.rate.inserts_allowed() == 0 && core.replay.ready_len() > 0 && !core.abort && !core.closed {
            core = self
                .wake
                .wait_timeout(core, Duration::from_millis(50))
                .expect("learner state lock poisoned")
                .0;
        }
        // The same step may have come in on another stream (a resend racing the broken
        // stream's last batch) while this one waited.
        if core.take_duplicate(header, step) {
            return Ok(Stored::Duplicate);
        }
        if core.closed {
            return Err(run_over(header.lease_id));
        }
        let now = self.now_ms();
        if step.step_index >= self.max_episode_steps {
            let why = Refusal::Episode(
                step.episode_id,
                format!(
                    "step {} beyond the episode cap of {} agent steps (max_agent_steps)",
                    step.step_index, self.max_episode_steps
                ),
            );
            core.break_lease(header, &why, now);
            return Err(why);
        }
        let ended = core.store(plane, header, step, now)?;
        if core.rate.inserts() >= self.budget {
            core.stopping = true;
        }
        if ended {
            core.verify_episode(step.episode_id);
            core.try_finish(header.lease_id, now);
        }
        drop(core);
        self.wake.notify_all();
        Ok(Stored::Inserted)
    }

    /// Handles an episode report: statistics, verification against the received steps, and the
    /// end of the lease once all its episodes are reported and complete.
    pub fn report(&self, r: &pb::EpisodeReport) -> Result<(), Refusal> {
        let run = r.run.clone().unwrap_or_default();
        self.validator.check_run(&run.run_id, run.incarnation)?;
        let now = self.now_ms();
        let mut core = self.lock();
        core.check_secret(r.actor_id, &r.actor_secret)?;
        if core.closed {
            return Err(run_over(r.lease_id));
        }
        core.registry
            .check_lease(r.actor_id, r.lease_id, now)
            .map_err(lease_refusal)?;
        // Nothing that could make the counters (and so a checkpoint) unreadable gets in.
        proto::validate::check_report(r)?;
        if r.policy_version > core.policy_version {
            return Err(Refusal::FutureVersion {
                got: r.policy_version,
                newest: core.policy_version,
            });
        }
        let in_lease = core
            .leases
            .get(r.lease_id)
            .is_some_and(|l| l.actor == r.actor_id && l.episode_ids().contains(&r.episode_id));
        if !in_lease {
            return Err(Refusal::Episode(
                r.episode_id,
                format!("not an episode of lease {}", r.lease_id),
            ));
        }
        let track = core.leases.episode_mut(r.episode_id);
        if track.reported.is_some() {
            return Err(Refusal::Episode(r.episode_id, "reported twice".into()));
        }
        track.reported = Some((r.steps, r.steps_checksum));
        // A report is proof of life: extend the lease like a heartbeat.
        core.registry
            .heartbeat(r.actor_id, Some(r.lease_id), now)
            .map_err(lease_refusal)?;
        core.registry
            .episode_done(r.actor_id, r.lease_id, now)
            .map_err(lease_refusal)?;
        let success = r.outcome == pb::Outcome::Success as i32;
        core.totals.record_episode(EpisodeStat {
            success,
            episode_return: r.episode_return,
            score: r.score,
        });
        let core = &mut *core;
        if let Some(lease) = core.leases.get_mut(r.lease_id) {
            lease.progress_ms = now;
            if let Some(kind) = core.totals.kinds.get_mut(lease.kind.as_str()) {
                kind.episodes += 1;
            }
        }
        core.verify_episode(r.episode_id);
        core.try_finish(r.lease_id, now);
        Ok(())
    }
}

impl Core {
    /// Whether `step` of `header`'s actor and lease was stored already (counted as a
    /// duplicate if so).
    fn take_duplicate(&mut self, header: &LeaseHeader, step: &StepView<'_>) -> bool {
        let stored = self
            .leases
            .stored_steps(header.lease_id, header.actor_id, step.episode_id);
        let duplicate = stored.is_some_and(|n| step.step_index < n);
        if duplicate {
            self.totals.steps_duplicate += 1;
        }
        duplicate
    }

    /// Stores one validated step under its lease. Returns whether it ended its episode. A
    /// refusal after the lease was found valid breaks the lease (its episode cannot complete).
    fn store(
        &mut self,
        plane: Plane,
        header: &LeaseHeader,
        step: &StepView<'_>,
        now: u64,
    ) -> Result<bool, Refusal> {
        self.registry
            .check_lease(header.actor_id, header.lease_id, now)
            .map_err(lease_refusal)?;
        let lease = self.leases.get(header.lease_id).ok_or_else(|| {
            Refusal::Lease(
                header.lease_id,
                "no assignment was handed out under this lease".into(),
            )
        })?;
        if lease.actor != header.actor_id {
            return Err(Refusal::Lease(
                header.lease_id,
                format!("belongs to actor {}", lease.actor),
            ));
        }
        let result = self.store_in_lease(plane, header.lease_id, step, now);
        if let Err(why) = &result {
            self.break_lease(header, why, now);
        }
        result
    }

    /// [`Self::store`] once the step's lease `lease_id` is known to be valid and the sender's.
    fn store_in_lease(
        &mut self,
        plane: Plane,
        lease_id: u64,
        step: &StepView<'_>,
        now: u64,
    ) -> Result<bool, Refusal> {
        let lease = self.leases.get(lease_id).expect("the caller found the lease");
        let range = lease.episode_ids();
        if !range.contains(&step.episode_id) {
            return Err(Refusal::Episode(
                step.episode_id,
                format!("not an episode of lease {} (expected {range:?})", lease_id),
            ));
        }
        if step.policy_version > self.policy_version {
            return Err(Refusal::FutureVersion {
                got: step.policy_version,
                newest: self.policy_version,
            });
        }
        let rank = lease.rank;
        let track = self.leases.episode_mut(step.episode_id);
        if track.ended {
            return Err(Refusal::Episode(step.episode_id, "already ended".into()));
        }
        if step.step_index != track.next_index {
            return Err(Refusal::Episode(
                step.episode_id,
                format!(
                    "step {} out of order (expected {})",
                    step.step_index, track.next_index
                ),
            ));
        }
        let end = match (step.terminal, step.truncated) {
            (true, _) => StepEnd::Terminal,
            (false, true) => StepEnd::Truncated {
                final_obs: step.final_obs,
            },
            _ => StepEnd::Continue,
        };
        self.replay
            .push(
                step.episode_id,
                &Step {
                    obs: step.obs,
                    action: step.action,
                    reward: step.reward,
                    end,
                },
            )
            .map_err(|e| Refusal::Episode(step.episode_id, e.to_string()))?;
        let track = self.leases.episode_mut(step.episode_id);
        track.next_index += 1;
        track.checksum = track.checksum.wrapping_add(step_checksum(step));
        let ended = step.terminal || step.truncated;
        track.ended = ended;
        self.rate.record_inserts(1);
        self.totals.steps_received += 1;
        *self.totals.rank_steps.entry(rank).or_default() += 1;
        let r = self.rank_entry(rank);
        match plane {
            Plane::Shm => r.steps_shm += 1,
            Plane::Grpc => r.steps_grpc += 1,
        }
        let lag = self.policy_version.saturating_sub(step.policy_version);
        self.lag.0 += lag;
        self.lag.1 += 1;
        if let Some(lease) = self.leases.get_mut(lease_id) {
            lease.progress_ms = now;
            if let Some(kind) = self.totals.kinds.get_mut(lease.kind.as_str()) {
                kind.steps += 1;
            }
        }
        Ok(ended)
    }
}

#[cfg(test)]
mod tests {
    use proto::validate::RefusalKind;

    use super::*;
    use crate::fixture::{fixture, report, step, td3_config};
    use crate::totals::Totals;
    use learner::config::Td3Config;

    #[test]
    fn a_nan_report_is_refused_and_counters_always_reach_a_resume() {
        let f = fixture(td3_config(), 60_000);
        let e = f.shared.report(&report(&f, f64::NAN)).unwrap_err();
        assert_eq!(e.kind(), RefusalKind::NotFinite, "{e}");
        let core = f.shared.lock();
        assert_eq!(core.totals.episodes_reported, 0);
        assert!(core.totals.recent.is_empty());
        drop(core);
        let mut future = report(&f, -3.0);
        future.policy_version = 7;
        let e = f.shared.report(&future).unwrap_err();
        assert!(e.to_string().contains("policy_version"), "{e}");
        // Counters written by a learner that let a NaN through (serde_json wrote `null`) still
        // load.
        let mut totals = Totals::default();
        totals.recent.push_back(EpisodeStat {
            success: false,
            episode_return: f64::NAN,
            score: f64::INFINITY,
        });
        let json = serde_json::to_value(&totals).unwrap();
        assert!(json["recent"][0]["episode_return"].is_null(), "{json}");
        let back: Totals = serde_json::from_value(json).unwrap();
        assert_eq!(back.recent[0].episode_return, 0.0);
        assert_eq!(back.recent[0].score, 0.0);
    }

    #[test]
    fn a_step_beyond_the_next_index_is_refused_and_ends_the_lease() {
        let f = fixture(td3_config(), 60_000);
        f.shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
            .unwrap();
        let e = f
            .shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 2))
            .unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Episode, "{e}");
        assert!(e.to_string().contains("out of order"), "{e}");
        f.shared.expire_leases_at(f.shared.now_ms());
        assert_eq!(f.shared.lock().totals.leases_dropped, 1);
    }

    #[test]
    fn once_the_run_is_over_steps_and_reports_are_refused_not_stored() {
        let f = fixture(td3_config(), 60_000);
        let ingest = |i: u32| f.shared.ingest(Plane::Grpc, &f.header, &step(f.first, i));
        assert_eq!(ingest(0), Ok(Stored::Inserted));
        f.shared.lock().closed = true;
        // What was stored is still recognised; nothing new is stored, and the actor is told.
        assert_eq!(ingest(0), Ok(Stored::Duplicate));
        let e = ingest(1).unwrap_err();
        assert!(e.to_string().contains("the run is over"), "{e}");
        let e = f.shared.report(&report(&f, 1.0)).unwrap_err();
        assert!(e.to_string().contains("the run is over"), "{e}");
        let core = f.shared.lock();
        assert_eq!(
            (core.totals.steps_received, core.totals.episodes_reported),
            (1, 0)
        );
    }

    #[test]
    fn a_resent_step_is_acknowledged_once_stored_even_after_its_lease_ended() {
        let f = fixture(td3_config(), 60_000);
        let ingest = |i: u32| f.shared.ingest(Plane::Grpc, &f.header, &step(f.first, i));
        assert_eq!(ingest(0), Ok(Stored::Inserted));
        assert_eq!(ingest(1), Ok(Stored::Inserted));
        // The same steps again (a batch resent after a broken connection): not stored twice,
        // and the lease stays valid.
        assert_eq!(ingest(0), Ok(Stored::Duplicate));
        assert_eq!(ingest(1), Ok(Stored::Duplicate));
        assert_eq!(ingest(2), Ok(Stored::Inserted));
        {
            let core = f.shared.lock();
            assert_eq!(core.totals.steps_received, 3);
            assert_eq!(core.totals.steps_duplicate, 2);
            assert_eq!(core.replay.len(), 3);
        }
        f.shared.expire_leases_at(f.shared.now_ms());
        assert_eq!(
            f.shared.lock().open_leases(),
            1,
            "duplicates do not break the lease"
        );
        // The lease ends (its actor is silent past the TTL): what it stored is still
        // recognised; what it did not store is refused with the lease's reason.
        f.shared.expire_leases_at(f.shared.now_ms() + 3_600_000);
        assert_eq!(f.shared.lock().open_leases(), 0);
        assert_eq!(ingest(1), Ok(Stored::Duplicate));
        let e = ingest(3).unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Lease, "{e}");
        // Another actor's header on the same lease is never taken for a duplicate.
        let mut other = f.header;
        other.actor_id += 1;
        assert!(f.shared.ingest(Plane::Grpc, &other, &step(f.first, 0)).is_err());
        let core = f.shared.lock();
        assert_eq!((core.totals.steps_received, core.totals.steps_duplicate), (3, 3));
    }

    #[test]
    fn inserts_never_wait_for_updates_that_cannot_run() {
        // No warm-up and room for one update: after one insert the limiter holds inserts back,
        // but with n-step 6 nothing is ready to sample, so no update can make room.
        let f = fixture(
            Td3Config {
                warmup_steps: 0,
                updates_per_insert: 1.0,
                rate_tolerance: 1.0,
                ..td3_config()
            },
            60_000,
        );
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let (shared, header, first) = (f.shared.clone(), f.header, f.first);
        std::thread::spawn(move || {
            for i in 0..3 {
                shared.ingest(Plane::Grpc, &header, &step(first, i)).unwrap();
            }
            done_tx.send(()).unwrap();
        });
        // A watchdog against the deadlock, not a timing assertion.
        done_rx
            .recv_timeout(Duration::from_secs(120))
            .expect("watchdog: ingest blocked although no update could run");
        assert_eq!(f.shared.lock().rate.inserts(), 3);
    }

    #[test]
    fn steps_of_a_policy_version_not_yet_published_are_refused() {
        let f = fixture(td3_config(), 60_000);
        let mut s = step(f.first, 0);
        s.policy_version = 3;
        let e = f.shared.ingest(Plane::Grpc, &f.header, &s).unwrap_err();
        assert!(e.to_string().contains("newer than the newest published"), "{e}");
    }
}
