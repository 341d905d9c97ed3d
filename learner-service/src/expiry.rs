//! Lease expiry, run every 100 ms by the learner: leases without a heartbeat within their TTL
//! expire, and leases that cannot or do not finish although their actor heartbeats are
//! dropped; their worlds are dealt again. Dead ranks are forgotten here too.

use scheduler::ExpiryCause;

use crate::shared::Shared;
use crate::status::ExpiredLease;

impl Shared {
    /// Expires overdue leases: their worlds go back to the pool and their unfinished episodes
    /// are abandoned in the replay buffer (never marked terminal).
    ///
    /// Also drops leases that cannot or do not finish although their actor keeps heartbeating:
    /// a lease with a refused step (its episode can never complete) at once, and a lease whose
    /// episodes made no progress (no step stored, no report accepted) for
    /// [`Shared::progress_timeout_ms`], or the registry's shorter stall bound (`[service]
    /// cycle_deadline_multiple` x the median episode time, at least its floor), which makes the
    /// actor late. The clock of the latter stands still while the learner
    /// itself holds the actors up (its rate limiter blocks inserts, or the current cycle's
    /// policy is not published yet). A dropped lease's actor learns it on its next heartbeat
    /// (`lease_valid: false`, with the reason).
    ///
    /// Leases the registry ended at a cycle's deadline (or a late actor's at its own) are
    /// counted as cut, logged, and their actors told why the same way. For every lease ended
    /// here the rule for its data is the same: the steps stored under it stay stored, each
    /// counted once (`steps_received`); its unfinished episodes are abandoned (never marked
    /// terminal, their unfinished n-step tail never sampled); steps sent under it later are
    /// refused, except a resent batch of stored ones, acknowledged as duplicates.
    pub fn expire_leases(&self) {
        self.expire_leases_at(self.now_ms());
    }

    /// [`Self::expire_leases`] at `now` (ms on the registry's clock).
    pub(crate) fn expire_leases_at(&self, now: u64) {
        let mut core = self.lock();
        let learner_holds = core.rate.inserts_allowed() == 0 || core.policy_version < core.registry.cycle();
        if learner_holds {
            core.registry.hold_deadlines(now);
        }
        let bound = core
            .registry
            .stall_bound_ms()
            .map_or(self.progress_timeout_ms, |stall| {
                stall.min(self.progress_timeout_ms)
            });
        let drop_now = core.leases.overdue(now, bound, learner_holds);
        let mut revoked = Vec::new();
        for (id, why, stalled) in drop_now {
            let ended = if stalled {
                core.registry.stall(id)
            } else {
                core.registry.revoke(id)
            };
            if ended {
                let (actor_id, rank) = core.leases.get(id).map_or((0, u32::MAX), |l| (l.actor, l.rank));
                tracing::warn!(
                    lease = id,
                    actor_id,
                    rank,
                    "lease dropped: {why}; its world is dealt again"
                );
                core.totals.leases_dropped += 1;
                core.leases.remember_dropped(id, why);
                revoked.push(id);
            }
            core.drop_lease(id);
        }
        let forgotten = core
            .registry
            .forget_dead_ranks(now, self.rank_forget_ms, self.dead_ranks_kept);
        for (rank, actors) in forgotten {
            core.forget_rank(rank, &actors);
        }
        for expired in core.registry.tick(now) {
            if revoked.contains(&expired.lease_id) {
                continue;
            }
            let rank = core.registry.rank_of(expired.actor).unwrap_or(u32::MAX);
            if let ExpiryCause::CycleDeadline { span_ms } | ExpiryCause::LeaseDeadline { span_ms } =
                expired.cause
            {
                let why = match expired.cause {
                    ExpiryCause::CycleDeadline { .. } => {
                        format!("the cycle's deadline passed ({span_ms} ms after its first assignment)")
                    }
                    _ => format!("a late actor's lease ran its span ({span_ms} ms)"),
                };
                tracing::warn!(
                    lease = expired.lease_id,
                    actor_id = expired.actor,
                    rank,
                    world = expired.world,
                    "lease ended: {why}; its world is dealt again, its stored steps are kept and its actor is late (off the cycle barrier until it finishes one)"
                );
                core.totals.leases_cut += 1;
                core.leases.remember_dropped(expired.lease_id, why);
                core.drop_lease(expired.lease_id);
                continue;
            }
            tracing::warn!(
                lease = expired.lease_id,
                actor_id = expired.actor,
                rank,
                world = expired.world,
                "lease expired; the world is dealt again"
            );
            core.totals.leases_expired += 1;
            core.leases.remember_expired(ExpiredLease {
                lease: expired.lease_id,
                actor_id: expired.actor,
                rank,
                world: expired.world,
            });
            core.drop_lease(expired.lease_id);
        }
        core.forget_retired();
        drop(core);
        self.wake.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use proto::plane::LeaseHeader;
    use proto::validate::RefusalKind;
    use scheduler::Decision;

    use crate::fixture::{fixture, step, td3_config, Fixture, TTL};
    use crate::ingest::Plane;
    use crate::status::{ExpiredLease, RankStatus, RefusedLease};

    #[test]
    fn a_refused_step_ends_its_lease_the_actor_is_told_and_the_cycle_advances() {
        let f = fixture(td3_config(), 60_000);
        f.shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
            .unwrap();
        let mut bad = step(f.first, 1);
        bad.reward = f32::NAN;
        assert_eq!(
            f.shared.ingest(Plane::Grpc, &f.header, &bad).unwrap_err().kind(),
            RefusalKind::NotFinite
        );
        // Every later step of the episode would be refused: the lease must not stay open.
        let now = f.shared.now_ms();
        f.shared.expire_leases_at(now);
        let core = f.shared.lock();
        assert_eq!(core.open_leases(), 0);
        assert_eq!((core.totals.leases_dropped, core.totals.leases_expired), (1, 0));
        assert_eq!(core.totals.episodes_abandoned, 1);
        assert!(core
            .registry
            .check_lease(f.header.actor_id, f.header.lease_id, now)
            .is_err());
        assert!(
            core.dropped_reason(f.header.lease_id)
                .is_some_and(|why| why.contains("reward")),
            "{:?}",
            core.dropped_reason(f.header.lease_id)
        );
        assert_eq!(core.registry.cycle(), 1, "the only actor's turn is over");
        assert_eq!(
            core.registry
                .status()
                .worlds
                .iter()
                .map(|w| w.completed)
                .sum::<u64>(),
            0
        );
    }

    #[test]
    fn a_lease_without_progress_is_dropped_although_heartbeats_keep_it_alive() {
        let timeout = 5 * TTL;
        let f = fixture(td3_config(), timeout);
        f.shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
            .unwrap();
        let progress = f.shared.now_ms();
        let heartbeat = |t: u64| {
            f.shared
                .lock()
                .registry
                .heartbeat(f.header.actor_id, Some(f.header.lease_id), t)
                .unwrap();
        };
        // A live heartbeat thread, a hung main loop: the TTL alone never ends the lease.
        for t in (0..10).map(|k| progress + k * TTL / 2) {
            heartbeat(t);
            f.shared.expire_leases_at(t);
            assert_eq!(f.shared.lock().open_leases(), 1, "at {t} ms");
        }
        let t = progress + timeout + 10;
        heartbeat(t - 20);
        f.shared.expire_leases_at(t);
        let core = f.shared.lock();
        assert_eq!(core.open_leases(), 0);
        assert_eq!((core.totals.leases_dropped, core.totals.leases_expired), (1, 0));
        assert!(core
            .dropped_reason(f.header.lease_id)
            .is_some_and(|why| why.contains("no progress")));
    }

    #[test]
    fn no_progress_clock_stands_still_while_the_learner_owes_the_policy() {
        let timeout = 2 * TTL;
        let f = fixture(td3_config(), timeout);
        // The cycle moved on but its policy is not published yet (e.g. a checkpoint is being
        // written): waiting actors are not at fault.
        f.shared.lock().registry.revoke(f.header.lease_id);
        let _ = f.shared.lock().registry.tick(0);
        f.shared.lock().drop_lease(f.header.lease_id);
        let f = {
            let mut core = f.shared.lock();
            assert_eq!(core.registry.cycle(), 1);
            let Decision::Assign(a) = core.registry.next_assignment(f.header.actor_id, 0, 0).unwrap() else {
                panic!("no assignment in cycle 1");
            };
            core.open_lease(a.lease_id, f.header.actor_id, a.episodes, 0);
            drop(core);
            Fixture {
                header: LeaseHeader {
                    lease_id: a.lease_id,
                    ..f.header
                },
                first: 0,
                shared: f.shared.clone(),
            }
        };
        let t = 10 * timeout;
        for beat in (0..t).step_by((TTL / 2) as usize) {
            f.shared
                .lock()
                .registry
                .heartbeat(f.header.actor_id, Some(f.header.lease_id), beat)
                .unwrap();
            f.shared.expire_leases_at(beat);
        }
        f.shared.expire_leases_at(t);
        assert_eq!(f.shared.lock().open_leases(), 1);
        assert_eq!(f.shared.lock().totals.leases_dropped, 0);
    }

    #[test]
    fn expired_leases_refusals_under_them_and_planes_are_counted_by_number() {
        let f = fixture(td3_config(), 60_000);
        f.shared.ingest(Plane::Shm, &f.header, &step(f.first, 0)).unwrap();
        // No heartbeat within the TTL: the lease expires; a late step under it is refused.
        f.shared.expire_leases_at(f.shared.now_ms() + 2 * TTL);
        let e = f
            .shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 1))
            .unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Lease, "{e}");
        let (lease, actor_id) = (f.header.lease_id, f.header.actor_id);
        assert_eq!(
            f.shared.refused_leases(),
            vec![RefusedLease { lease, records: 1 }]
        );
        let core = f.shared.lock();
        let expired: Vec<ExpiredLease> = core.expired_recent().copied().collect();
        assert_eq!(expired.len(), 1);
        assert_eq!(
            (expired[0].lease, expired[0].actor_id, expired[0].rank),
            (lease, actor_id, 0)
        );
        let ranks: Vec<RankStatus> = core.ranks().cloned().collect();
        assert_eq!(
            ranks,
            vec![RankStatus {
                rank: 0,
                registrations: 1,
                actor_ids: vec![actor_id],
                steps_shm: 1,
                steps_grpc: 0,
            }]
        );
    }
}
