//! `adp bench transport`: the throughput of the two step planes, measured through the wire
//! crate's public sinks and sources, as actors and the learner use them.
//!
//! Both benchmarks send the same records (730 observation floats and 4 action floats each) from
//! `publishers` threads (`publish`) and copy every received observation into a ring of 1024
//! rows, as the learner copies into its buffer.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Barrier, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use proto::grpc::{for_each_step, DecodeScratch, GrpcStepSink, LearnerAddress, MAX_MESSAGE_BYTES};
use proto::pb;
use proto::plane::{LeaseHeader, PlaneError, StepSink};
use proto::shm::{ShmConfig, ShmStepSink, ShmStepSource};
use proto::StepView;
use tonic::service::interceptor::InterceptedService;
use tonic::{Request, Response, Status, Streaming};

use crate::{figure, Figure};

/// Observation floats per record.
const OBS: usize = 730;
/// Rows of the receiving ring.
const ROWS: usize = 1024;

/// Publisher `i`'s share of `records` spread over `publishers`.
fn share(records: usize, publishers: usize, i: usize) -> usize {
    records / publishers + usize::from(i < records % publishers)
}

/// Sends `count` step records of actor `actor` through `sink`, flushing every `flush_every`
/// records (if any) and at the end.
fn publish(
    sink: &mut impl StepSink,
    actor: u64,
    count: usize,
    flush_every: Option<usize>,
) -> Result<(), PlaneError> {
    let obs = vec![0.5f32; OBS];
    let header = LeaseHeader {
        incarnation: 1,
        actor_id: actor,
        lease_id: 1,
        secret: [0; 16],
    };
    for k in 0..count {
        let step = StepView {
            episode_id: 0,
            step_index: k as u32,
            policy_version: 0,
            obs: &obs,
            action: &[0.0; 4],
            reward: -0.5,
            terminal: false,
            truncated: false,
            final_obs: &[],
        };
        sink.send(&header, &step)?;
        if flush_every.is_some_and(|n| (k + 1) % n == 0) {
            sink.flush()?;
        }
    }
    sink.flush()
}

/// Copies `obs` into the ring `rows` at row `*next`, advancing it.
fn store(rows: &mut [f32], next: &mut usize, obs: &[f32]) {
    let len = obs.len().min(OBS);
    rows[*next * OBS..*next * OBS + len].copy_from_slice(&obs[..len]);
    *next = (*next + 1) % ROWS;
}

/// Measures the shared-memory step plane: `publishers` threads (each its own node, as actors
/// are) send `records` step records in total while one subscriber drains them. Returns records
/// per second from the start of sending to the last record received. Uses a private service
/// name under the default iceoryx2 root.
pub fn shm_throughput(records: usize, publishers: usize) -> anyhow::Result<f64> {
    static RUNS: AtomicUsize = AtomicUsize::new(0);
    let publishers = publishers.max(1);
    let cfg = ShmConfig {
        service_prefix: format!(
            "adp-bench/{}/{}",
            std::process::id(),
            RUNS.fetch_add(1, Ordering::Relaxed)
        ),
        max_actors: publishers.max(ShmConfig::default().max_actors),
        ..ShmConfig::default()
    };
    let mut source = ShmStepSource::open(&cfg)?;
    let start = Arc::new(Barrier::new(publishers + 1));
    let senders: Vec<JoinHandle<Result<(), PlaneError>>> = (0..publishers)
        .map(|i| {
            let (cfg, start) = (cfg.clone(), Arc::clone(&start));
            let count = share(records, publishers, i);
            thread::spawn(move || {
                let sink = ShmStepSink::open(&cfg, &format!("adp-bench-actor-{i}"));
                start.wait();
                publish(&mut sink?, i as u64, count, None)
            })
        })
        .collect();
    start.wait();
    let t0 = Instant::now();
    let mut ring = vec![0f32; ROWS * OBS];
    let mut row = 0;
    let mut received = 0;
    while received < records {
        let n = source.drain(256, |_, step| store(&mut ring, &mut row, step.obs))?;
        received += n;
        if n == 0 {
            if senders.iter().all(|s| s.is_finished()) && received < records {
                break;
            }
            thread::yield_now();
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    for (i, sender) in senders.into_iter().enumerate() {
        match sender.join() {
            Ok(outcome) => outcome.with_context(|| format!("shared-memory bench publisher {i}"))?,
            Err(_) => bail!("shared-memory bench publisher {i} panicked"),
        }
    }
    if received < records {
        bail!("shared-memory bench: received {received} of {records} records");
    }
    Ok(records as f64 / secs)
}

/// The gRPC benchmark's server side: decodes and stores, acknowledges every record.
struct Sink {
    received: Arc<AtomicU64>,
    ring: Arc<Mutex<(Vec<f32>, usize)>>,
}

type NoPolicies =
    std::pin::Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::PolicySnapshot, Status>> + Send>>;

#[tonic::async_trait]
impl pb::data_server::Data for Sink {
    async fn push_steps(
        &self,
        batches: Request<Streaming<pb::StepBatch>>,
    ) -> Result<Response<pb::Ack>, Status> {
        let mut scratch = DecodeScratch::default();
        let mut ack = pb::Ack::default();
        let mut stream = batches.into_inner();
        while let Some(batch) = stream.message().await? {
            let mut ring = self.ring.lock().expect("bench ring");
            let (rows, next) = &mut *ring;
            for_each_step(&batch, &mut scratch, |step| {
                if let Ok(step) = step {
                    store(rows, next, step.obs);
                    ack.accepted += 1;
                } else {
                    ack.refused += 1;
                }
            });
            self.received
                .fetch_add(batch.steps.len() as u64, Ordering::Relaxed);
        }
        Ok(Response::new(ack))
    }

    type WatchPolicyStream = NoPolicies;

    async fn watch_policy(&self, _: Request<pb::PolicyRequest>) -> Result<Response<NoPolicies>, Status> {
        Err(Status::unimplemented("the benchmark serves no policies"))
    }
}

/// Measures the gRPC step plane over loopback: a server with the token interceptor decodes
/// every batch, while `publishers` threads, each on its own connection and [`GrpcStepSink`] as
/// actors are, send `records` step records in total, flushing (close the stream, await the
/// acknowledgement) every 200 records as an actor does at the end of an episode. Returns records
/// per second from the start of sending to the last acknowledgement.
pub fn grpc_throughput(records: usize, publishers: usize) -> anyhow::Result<f64> {
    const FLUSH_EVERY: usize = 200;
    const TOKEN: &str = "bench";

    let publishers = publishers.max(1);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start a tokio runtime")?;
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .context("cannot listen on loopback")?;
    let addr = listener.local_addr()?;
    let received = Arc::new(AtomicU64::new(0));
    let sink = Sink {
        received: received.clone(),
        ring: Arc::new(Mutex::new((vec![0f32; ROWS * OBS], 0))),
    };
    let auth = proto::auth::ServerAuth::new(TOKEN, Arc::default());
    let service = InterceptedService::new(
        pb::data_server::DataServer::new(sink)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES),
        auth,
    );
    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);
    let server = runtime.spawn(
        tonic::transport::Server::builder()
            .add_service(service)
            .serve_with_incoming_shutdown(
                tokio_stream::wrappers::TcpListenerStream::new(listener),
                async move {
                    let _ = stop_rx.wait_for(|s| *s).await;
                },
            ),
    );
    let address = LearnerAddress {
        addr: addr.to_string(),
        token: Some(TOKEN.into()),
        tls: None,
    };
    let start = Arc::new(Barrier::new(publishers + 1));
    let senders: Vec<JoinHandle<anyhow::Result<()>>> = (0..publishers)
        .map(|i| {
            let (handle, address, start) = (runtime.handle().clone(), address.clone(), start.clone());
            let count = share(records, publishers, i);
            thread::spawn(move || {
                let connected = handle.block_on(address.connect());
                start.wait();
                let (_, data) = connected?;
                let mut sink = GrpcStepSink::new(handle, data, "bench", 1, Duration::from_secs(60));
                Ok(publish(&mut sink, i as u64, count, Some(FLUSH_EVERY))?)
            })
        })
        .collect();
    start.wait();
    let t0 = Instant::now();
    let mut failure = None;
    for (i, sender) in senders.into_iter().enumerate() {
        let outcome = sender.join().unwrap_or_else(|_| Err(anyhow!("panicked")));
        if let Err(e) = outcome {
            failure.get_or_insert(e.context(format!("gRPC bench publisher {i}")));
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let _ = stop_tx.send(true);
    let _ = runtime.block_on(server);
    if let Some(e) = failure {
        return Err(e);
    }
    let got = received.load(Ordering::Relaxed);
    if got != records as u64 {
        bail!("gRPC bench: received {got} of {records} records");
    }
    Ok(records as f64 / secs)
}

/// The `transport` part's figures: `records` step records (at least 1000) through shared
/// memory and a quarter of them through gRPC, from 4 publishers each.
pub fn run(records: usize) -> anyhow::Result<Vec<Figure>> {
    let records = records.max(1000);
    let shm = shm_throughput(records, 4)?;
    let grpc = grpc_throughput(records / 4, 4)?;
    Ok(vec![
        figure(
            "shared-memory step records/s (4 publishers, 730 floats)",
            shm,
            "1/s",
        )
        .at_least(100_000.0),
        figure("gRPC loopback step records/s (4 connections, token)", grpc, "1/s").at_least(20_000.0),
    ])
}

#[cfg(test)]
mod tests {
    use testkit::watchdog;

    use super::*;

    #[test]
    fn shm_bench_runs() {
        let _w = watchdog(60, "small bench");
        let rate = shm_throughput(2000, 2).unwrap();
        assert!(rate > 0.0);
    }

    #[test]
    fn grpc_bench_delivers_every_record_from_every_publisher() {
        let _w = watchdog(120, "gRPC bench");
        // 1001 records over 3 publishers: uneven shares and a partial last batch.
        let rate = grpc_throughput(1001, 3).unwrap();
        assert!(rate.is_finite() && rate > 0.0, "{rate}");
    }
}
