//! Timing of the hot paths at the paper's sizes (ignored by default; run with
//! `cargo nextest run -p million --cargo-profile release --run-ignored only -E 'binary(speed)' --no-capture`).
//! Threads: MILLION_BENCH_THREADS (default 1).

use std::time::Instant;

use million::algo::buffer::SegmentBatch;
use million::config::AgentConfig;
use million::learner::Learner;
use tch::{Device, Kind, Tensor};

fn threads() -> i32 {
    std::env::var("MILLION_BENCH_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

fn random_batch(cfg: &AgentConfig, b: i64) -> SegmentBatch {
    let m = &cfg.model;
    let t = m.segment_len as i64;
    let a = m.action_dim as i64;
    let opts = (Kind::Float, Device::Cpu);
    let flags = |p: f64| Tensor::rand([b, t], opts).lt(p);
    SegmentBatch {
        obs: Tensor::randn([b, t, m.obs_dim() as i64], opts),
        actions: Tensor::randn([b, t, a], opts),
        rewards: Tensor::randn([b, t], opts),
        terminated: flags(0.003),
        truncated: flags(0.0),
        episode_start: flags(0.003),
        instruction: flags(0.1),
        task: Tensor::randint(10, [b, t], (Kind::Int64, Device::Cpu)),
        behaviour_mean: Tensor::randn([b, t, a], opts).tanh(),
        behaviour_std: Tensor::rand([b, t, a], opts) + 0.3,
        memory: Tensor::randn(
            [m.layers as i64, b, m.memory_len as i64, m.d_model as i64],
            opts,
        ),
        memory_len: Tensor::full([b], m.memory_len as i64, (Kind::Int64, Device::Cpu)),
    }
}

#[test]
#[ignore = "benchmark"]
fn learner_update_and_acting_step_at_paper_size() {
    tch::set_num_threads(threads());
    let cfg = AgentConfig::default();
    let mut learner = Learner::new(cfg.clone(), Device::Cpu);
    let batch = random_batch(&cfg, cfg.buffer.batch_segments as i64);
    learner.update(&batch).unwrap();
    let n = 3;
    let start = Instant::now();
    for _ in 0..n {
        learner.update(&batch).unwrap();
    }
    let update_s = start.elapsed().as_secs_f64() / n as f64;
    println!(
        "threads {} learner update b={} T={}: {:.3} s",
        threads(),
        cfg.buffer.batch_segments,
        cfg.model.segment_len,
        update_s
    );
    let model = learner.model();
    let start = Instant::now();
    for _ in 0..n {
        let out = tch::no_grad(|| {
            model.forward_segment(
                &batch.obs,
                &batch.episode_start,
                &batch.memory,
                &batch.memory_len,
            )
        });
        assert_eq!(out.mean.size()[0], cfg.buffer.batch_segments as i64);
    }
    println!(
        "threads {} forward only (no grad): {:.3} s",
        threads(),
        start.elapsed().as_secs_f64() / n as f64
    );
    for slots in [32i64, 128] {
        let mut state = model.acting_state(slots);
        let obs = Tensor::randn(
            [slots, cfg.model.obs_dim() as i64],
            (Kind::Float, Device::Cpu),
        );
        let no = Tensor::zeros([slots], (Kind::Bool, Device::Cpu));
        let steps = 2 * cfg.model.segment_len;
        for _ in 0..8 {
            model.act(&mut state, &obs, &no);
        }
        let start = Instant::now();
        for _ in 0..steps {
            model.act(&mut state, &obs, &no);
        }
        let step_s = start.elapsed().as_secs_f64() / steps as f64;
        println!(
            "threads {} acting step, {slots} slots: {:.2} ms ({:.0} agent steps/s of inference)",
            threads(),
            step_s * 1e3,
            slots as f64 / step_s
        );
    }
}
