//! The FIFO segment buffer: order, uniform sampling, replay-ratio throttling.

use million::algo::buffer::{Segment, SegmentBuffer};
use million::config::BufferConfig;
use rand::SeedableRng;
use rand::rngs::StdRng;
use tch::{Device, Kind, Tensor};

/// A 2-step segment whose observations all equal `id`.
fn segment(id: i64) -> Segment {
    let f = |shape: &[i64]| Tensor::zeros(shape, (Kind::Float, Device::Cpu));
    let b = |shape: &[i64]| Tensor::zeros(shape, (Kind::Bool, Device::Cpu));
    Segment {
        obs: Tensor::full([2, 3], id as f64, (Kind::Float, Device::Cpu)),
        actions: f(&[2, 1]),
        rewards: f(&[2]),
        terminated: b(&[2]),
        truncated: b(&[2]),
        episode_start: b(&[2]),
        instruction: b(&[2]),
        task: Tensor::full([2], id, (Kind::Int64, Device::Cpu)),
        behaviour_mean: f(&[2, 1]),
        behaviour_std: f(&[2, 1]),
        bootstrap_obs: Tensor::full([3], id as f64, (Kind::Float, Device::Cpu)),
        bootstrap_start: Tensor::from(false),
        memory: Tensor::full([1, 4, 2], id as f64, (Kind::Float, Device::Cpu)),
        memory_len: Tensor::from(id),
    }
}

fn ids(buffer: &SegmentBuffer) -> Vec<i64> {
    buffer
        .iter()
        .map(|s| s.obs.double_value(&[0, 0]) as i64)
        .collect()
}

fn config(batch: usize, period: usize, ratio: f64) -> BufferConfig {
    BufferConfig {
        batch_segments: batch,
        target_period: period,
        replay_ratio: ratio,
        min_segments: batch,
        ..BufferConfig::default()
    }
}

#[test]
fn the_oldest_segments_leave_first() {
    let mut buf = SegmentBuffer::new(&config(1, 3, 4.0));
    assert_eq!(buf.capacity(), 3);
    for id in 0..5 {
        buf.push(segment(id));
    }
    assert_eq!(ids(&buf), vec![2, 3, 4]);
}

#[test]
fn sampling_is_uniform_over_the_buffer_and_stacks_fields() {
    let mut buf = SegmentBuffer::new(&config(2, 3, 1e9));
    for id in 0..10 {
        buf.push(segment(id));
    }
    let mut rng = StdRng::seed_from_u64(1);
    let mut counts = [0u32; 10];
    for _ in 0..2000 {
        let batch = buf.sample(&mut rng).unwrap();
        assert_eq!(batch.obs.size(), vec![2, 2, 3]);
        assert_eq!(batch.memory.size(), vec![1, 2, 4, 2]);
        let a = batch.obs.double_value(&[0, 0, 0]) as usize;
        let b = batch.obs.double_value(&[1, 0, 0]) as usize;
        assert_ne!(a, b, "a batch holds distinct segments");
        // Fields stay aligned per segment.
        assert_eq!(batch.task.int64_value(&[0, 1]) as usize, a);
        assert_eq!(batch.memory_len.int64_value(&[1]) as usize, b);
        assert_eq!(batch.memory.double_value(&[0, 1, 3, 1]) as usize, b);
        counts[a] += 1;
        counts[b] += 1;
    }
    assert_eq!(counts[..4], [0; 4], "evicted segments are never sampled");
    // 4000 draws over 6 segments: 667 each; ±20% is > 5 standard deviations.
    for &c in &counts[4..] {
        assert!((533..=800).contains(&c), "{counts:?}");
    }
}

#[test]
fn the_learner_is_throttled_to_the_replay_ratio() {
    let mut buf = SegmentBuffer::new(&config(2, 10, 1.5));
    let mut rng = StdRng::seed_from_u64(2);
    buf.push(segment(0));
    assert!(!buf.ready(), "fewer segments than a batch");
    buf.push(segment(1));
    buf.push(segment(2));
    buf.push(segment(3));
    // produced 4, ratio 1.5 → at most 6 consumed: three batches of 2.
    for _ in 0..3 {
        assert!(buf.sample(&mut rng).is_some());
    }
    assert!(buf.sample(&mut rng).is_none());
    assert_eq!(buf.replay_ratio(), 1.5);
    buf.push(segment(4));
    assert!(!buf.ready(), "8 > 1.5 · 5");
    buf.push(segment(5));
    assert!(buf.ready(), "8 ≤ 1.5 · 6");
    let c = buf.counters();
    assert_eq!((c.produced_segments, c.consumed_segments), (6, 6));
}
