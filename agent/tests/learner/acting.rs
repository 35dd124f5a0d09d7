//! Incremental acting produces what the learner recomputes from the stored segment.

use crate::common::{max_abs_diff, randomise_relative_bias, small_model};
use million::algo::rollout::{NextObservation, RolloutCollector, StepRecord};
use million::config::PopArtConfig;
use million::model::Model;
use million::model::policy::sample_actions;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

fn check_acting_equals_learning(segment_len: usize, memory_len: usize) {
    // One intra-op thread: two spin-waiting pools on a shared 2-core machine crawl.
    tch::set_num_threads(1);
    tch::manual_seed(3);
    let vs = VarStore::new(Device::Cpu);
    let model = Model::new(
        &vs.root(),
        &small_model(segment_len, memory_len),
        &PopArtConfig::default(),
    );
    randomise_relative_bias(&vs);
    let slots = 4;
    let t_len = segment_len as i64;
    let mut state = model.acting_state(slots);
    let mut collector = RolloutCollector::new(segment_len);
    let mut batches = vec![];
    // Episode starts: all slots at step 0; slot 1 again mid-segment, slot 2 at a segment
    // start, slot 3 on the last step of a segment.
    let starts_at = |slot: i64, step: i64| {
        step == 0
            || (slot == 1 && step == t_len + 3)
            || (slot == 2 && step == 2 * t_len)
            || (slot == 3 && step == t_len - 1)
    };
    let observations: Vec<Tensor> = (0..=3 * t_len)
        .map(|_| Tensor::randn([slots, 10], (Kind::Float, Device::Cpu)))
        .collect();
    let starts: Vec<Tensor> = (0..=3 * t_len)
        .map(|step| Tensor::from_slice(&(0..slots).map(|s| starts_at(s, step)).collect::<Vec<_>>()))
        .collect();
    for step in 0..3 * t_len {
        if collector.is_at_segment_start() {
            let (memory, len) = state.segment_start_memory();
            collector.begin(memory, len);
        }
        let (obs, episode_start) = (&observations[step as usize], &starts[step as usize]);
        let out = model.act(&mut state, obs, episode_start);
        let zeros = Tensor::zeros([slots], (Kind::Float, Device::Cpu));
        let done = zeros.to_kind(Kind::Bool);
        let next = NextObservation {
            obs: &observations[step as usize + 1],
            episode_start: &starts[step as usize + 1],
        };
        let batch = collector
            .push(
                StepRecord {
                    action: sample_actions(&out.mean, &out.std),
                    obs: obs.shallow_clone(),
                    episode_start: episode_start.shallow_clone(),
                    reward: zeros,
                    terminated: done.shallow_clone(),
                    truncated: done.shallow_clone(),
                    instruction: done,
                    task: Tensor::zeros([slots], (Kind::Int64, Device::Cpu)),
                    behaviour_mean: out.mean,
                    behaviour_std: out.std,
                },
                next,
            )
            .unwrap();
        batches.extend(batch);
    }
    assert_eq!(batches.len(), 3);
    let mut previous_next_memory: Option<Tensor> = None;
    for (i, b) in batches.iter().enumerate() {
        let out = tch::no_grad(|| {
            model.forward_segment(&b.obs, &b.episode_start, &b.memory, &b.memory_len)
        });
        let mean_diff = max_abs_diff(&out.mean, &b.behaviour_mean);
        let std_diff = max_abs_diff(&out.std, &b.behaviour_std);
        assert!(
            mean_diff < 1e-5 && std_diff < 1e-5,
            "segment {i}: mean {mean_diff} std {std_diff}"
        );
        if let Some(prev) = &previous_next_memory {
            assert!(max_abs_diff(prev, &b.memory) < 1e-5, "segment {i} memory");
        }
        previous_next_memory = Some(out.core.next_memory());
        // The state after the segment is kept with it, and running it as one more step
        // (`vmpo.learn_last_step`) leaves the segment's own outputs as they acted.
        let after = (i as i64 + 1) * t_len;
        assert!(max_abs_diff(&b.bootstrap_obs, &observations[after as usize]) == 0.0);
        assert!(b.bootstrap_start.equal(&starts[after as usize]));
        let extended = tch::no_grad(|| {
            model.forward_segment(
                &Tensor::cat(&[&b.obs, &b.bootstrap_obs.unsqueeze(1)], 1),
                &Tensor::cat(&[&b.episode_start, &b.bootstrap_start.unsqueeze(1)], 1),
                &b.memory,
                &b.memory_len,
            )
        });
        let diff = max_abs_diff(&extended.mean.narrow(1, 0, t_len), &b.behaviour_mean);
        assert!(
            diff < 1e-5,
            "segment {i} with the state after it: mean {diff}"
        );
    }
    // Slot 1 reset at step 3 of segment 1: its memory for segment 2 keeps min(m, T−3) rows.
    let expected = (memory_len as i64).min(t_len - 3);
    assert_eq!(batches[2].memory_len.int64_value(&[1]), expected);
}

#[test]
fn incremental_acting_equals_the_batched_segment_pass() {
    check_acting_equals_learning(8, 8);
}

#[test]
fn incremental_acting_equals_the_batched_segment_pass_with_short_memory() {
    check_acting_equals_learning(8, 5);
}

#[test]
fn a_collector_refuses_steps_before_the_segment_memory() {
    let mut c = RolloutCollector::new(2);
    let z = Tensor::zeros([1], (Kind::Float, Device::Cpu));
    let err = c
        .push(
            StepRecord {
                obs: z.shallow_clone(),
                episode_start: z.shallow_clone(),
                action: z.shallow_clone(),
                reward: z.shallow_clone(),
                terminated: z.shallow_clone(),
                truncated: z.shallow_clone(),
                instruction: z.shallow_clone(),
                task: z.shallow_clone(),
                behaviour_mean: z.shallow_clone(),
                behaviour_std: z.shallow_clone(),
            },
            NextObservation {
                obs: &z,
                episode_start: &z,
            },
        )
        .unwrap_err();
    assert!(err.to_string().contains("memory"));
}
