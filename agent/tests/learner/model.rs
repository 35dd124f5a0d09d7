//! The GTrXL model: causality, memory across segments, episode masking, gates at init.

use crate::common::{max_abs_diff, random_starts, randomise_relative_bias, small_model};
use million::config::PopArtConfig;
use million::model::Model;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

fn model(segment_len: usize, memory_len: usize) -> (VarStore, Model) {
    // One intra-op thread: two spin-waiting pools on a shared 2-core machine crawl.
    tch::set_num_threads(1);
    tch::manual_seed(7);
    let vs = VarStore::new(Device::Cpu);
    let m = Model::new(
        &vs.root(),
        &small_model(segment_len, memory_len),
        &PopArtConfig::default(),
    );
    randomise_relative_bias(&vs);
    (vs, m)
}

fn outputs(model: &Model, obs: &Tensor, starts: &Tensor, mem: &(Tensor, Tensor)) -> Tensor {
    let out = tch::no_grad(|| model.forward_segment(obs, starts, &mem.0, &mem.1));
    Tensor::cat(&[out.mean, out.std, out.value_features], -1)
}

#[test]
fn changing_later_inputs_leaves_earlier_outputs_unchanged() {
    let (_vs, model) = model(8, 8);
    let obs = Tensor::randn([3, 8, 10], (Kind::Float, Device::Cpu));
    let starts = random_starts(3, 8, 0.2);
    let mem = (
        Tensor::randn([2, 3, 8, 16], (Kind::Float, Device::Cpu)),
        Tensor::from_slice(&[8i64, 3, 0]),
    );
    let before = outputs(&model, &obs, &starts, &mem);
    let changed = obs.copy();
    let _ = changed.narrow(1, 5, 3).fill_(9.0);
    let after = outputs(&model, &changed, &starts, &mem);
    assert!(max_abs_diff(&before.narrow(1, 0, 5), &after.narrow(1, 0, 5)) < 1e-6);
    // The change is visible from step 5 on (so the check above could fail).
    assert!(max_abs_diff(&before.narrow(1, 5, 3), &after.narrow(1, 5, 3)) > 1e-3);
}

#[test]
fn segments_with_memory_equal_the_whole_sequence() {
    // T = m = 8 in two segments sees exactly what one 16-step segment sees; both models have a
    // relative-bias table of 16 distances and share all weights.
    let (vs_split, split) = model(8, 8);
    let mut vs_whole = VarStore::new(Device::Cpu);
    let whole = Model::new(
        &vs_whole.root(),
        &small_model(16, 0),
        &PopArtConfig::default(),
    );
    vs_whole.copy(&vs_split).unwrap();

    let obs = Tensor::randn([3, 16, 10], (Kind::Float, Device::Cpu));
    let starts = Tensor::zeros([3, 16], (Kind::Bool, Device::Cpu));
    let _ = starts.narrow(1, 0, 1).fill_(1);
    let _ = starts.get(1).narrow(0, 5, 1).fill_(1); // inside segment 1
    let _ = starts.get(2).narrow(0, 11, 1).fill_(1); // inside segment 2
    let _ = starts.get(0).narrow(0, 8, 1).fill_(1); // exactly at the boundary

    let whole_out = outputs(
        &whole,
        &obs,
        &starts,
        &whole.core().empty_memory(3, Device::Cpu),
    );
    let first = tch::no_grad(|| {
        let (m, l) = split.core().empty_memory(3, Device::Cpu);
        split.forward_segment(&obs.narrow(1, 0, 8), &starts.narrow(1, 0, 8), &m, &l)
    });
    let second = outputs(
        &split,
        &obs.narrow(1, 8, 8),
        &starts.narrow(1, 8, 8),
        &(
            first.core.next_memory(),
            first.core.next_memory_len.shallow_clone(),
        ),
    );
    let first = Tensor::cat(&[first.mean, first.std, first.value_features], -1);
    assert!(max_abs_diff(&whole_out.narrow(1, 0, 8), &first) < 1e-5);
    assert!(max_abs_diff(&whole_out.narrow(1, 8, 8), &second) < 1e-5);
    // Valid memory rows after segment 1: slot 0 all 8, slot 1 the 3 steps since its reset at 5.
    assert_eq!(
        Vec::<i64>::try_from(second_len(&split, &obs, &starts)).unwrap(),
        vec![8, 3, 8]
    );
}

fn second_len(model: &Model, obs: &Tensor, starts: &Tensor) -> Tensor {
    let (m, l) = model.core().empty_memory(3, Device::Cpu);
    tch::no_grad(|| model.forward_segment(&obs.narrow(1, 0, 8), &starts.narrow(1, 0, 8), &m, &l))
        .core
        .next_memory_len
}

#[test]
fn a_new_episode_never_sees_the_previous_one() {
    // Steps 6.. of a sequence with a reset at 6 equal a fresh run on those steps, whatever the
    // memory and the earlier steps were.
    let (_vs, model) = model(16, 8);
    let obs = Tensor::randn([2, 16, 10], (Kind::Float, Device::Cpu));
    let starts = Tensor::zeros([2, 16], (Kind::Bool, Device::Cpu));
    let _ = starts.narrow(1, 6, 1).fill_(1);
    let mem = (
        Tensor::randn([2, 2, 8, 16], (Kind::Float, Device::Cpu)),
        Tensor::from_slice(&[8i64, 8]),
    );
    let with_history = outputs(&model, &obs, &starts, &mem);

    let fresh_obs = Tensor::cat(
        &[
            obs.narrow(1, 6, 10),
            Tensor::randn([2, 6, 10], (Kind::Float, Device::Cpu)),
        ],
        1,
    );
    let fresh_starts = Tensor::zeros([2, 16], (Kind::Bool, Device::Cpu));
    let _ = fresh_starts.narrow(1, 0, 1).fill_(1);
    let fresh = outputs(
        &model,
        &fresh_obs,
        &fresh_starts,
        &model.core().empty_memory(2, Device::Cpu),
    );
    assert!(max_abs_diff(&with_history.narrow(1, 6, 10), &fresh.narrow(1, 0, 10)) < 1e-5);
    // Without the reset the history does matter.
    let no_reset = outputs(
        &model,
        &obs,
        &Tensor::zeros([2, 16], (Kind::Bool, Device::Cpu)),
        &mem,
    );
    assert!(max_abs_diff(&no_reset.narrow(1, 6, 10), &fresh.narrow(1, 0, 10)) > 1e-3);
}

#[test]
fn memory_is_ignored_when_its_length_is_zero() {
    let (_vs, model) = model(8, 8);
    let obs = Tensor::randn([2, 8, 10], (Kind::Float, Device::Cpu));
    let starts = Tensor::zeros([2, 8], (Kind::Bool, Device::Cpu));
    let empty = model.core().empty_memory(2, Device::Cpu);
    let garbage = (
        Tensor::randn([2, 2, 8, 16], (Kind::Float, Device::Cpu)),
        empty.1.shallow_clone(),
    );
    assert!(
        max_abs_diff(
            &outputs(&model, &obs, &starts, &empty),
            &outputs(&model, &obs, &starts, &garbage)
        ) < 1e-6
    );
}

#[test]
fn gates_are_near_identity_at_initialisation() {
    let (_vs, model) = model(8, 8);
    let gate = model.core().layers()[0].gate_attn();
    // With no input the update gate is exactly σ(−b_g) = σ(−2).
    let zero = Tensor::zeros([4, 16], (Kind::Float, Device::Cpu));
    let (out, z) = tch::no_grad(|| gate.forward_with_update_gate(&zero, &zero));
    let expected = 1.0 / (1.0 + 2f64.exp());
    assert!((z.mean(Kind::Float).double_value(&[]) - expected).abs() < 1e-6);
    assert!(out.abs().max().double_value(&[]) < 1e-7);
    // For unit-scale inputs the gate still mostly passes x through.
    let x = Tensor::randn([256, 16], (Kind::Float, Device::Cpu));
    let y = Tensor::randn([256, 16], (Kind::Float, Device::Cpu)).relu();
    let (out, z) = tch::no_grad(|| gate.forward_with_update_gate(&x, &y));
    let mean_z = z.mean(Kind::Float).double_value(&[]);
    assert!(mean_z > 0.05 && mean_z < 0.25, "mean update gate {mean_z}");
    let rel = ((&out - &x).norm().double_value(&[])) / x.norm().double_value(&[]);
    assert!(rel < 0.4, "relative change {rel}");
}

#[test]
fn instruction_slots_reach_every_step_and_the_paper_model_has_none() {
    tch::set_num_threads(1);
    tch::manual_seed(5);
    let paper = VarStore::new(Device::Cpu);
    let _ = Model::new(&paper.root(), &small_model(4, 4), &PopArtConfig::default());
    assert!(
        !paper
            .variables()
            .keys()
            .any(|k| k.starts_with("instruction")),
        "instruction_words = 0 must build the paper's network"
    );
    let cfg = million::config::ModelConfig {
        instruction_words: 2,
        ..small_model(4, 4)
    };
    let vs = VarStore::new(Device::Cpu);
    let model = Model::new(&vs.root(), &cfg, &PopArtConfig::default());
    let (fields, dim) = (cfg.fields_dim() as i64, cfg.obs_dim() as i64);
    assert_eq!(dim, fields + 2 * 4);
    let obs = Tensor::randn([1, 4, dim], (Kind::Float, Device::Cpu));
    // Slot 0 valid at every step, slot 1 empty.
    let _ = obs.narrow(2, fields, 1).fill_(1.0);
    let _ = obs.narrow(2, fields + 4, 4).fill_(0.0);
    let obs = obs.set_requires_grad(true);
    let starts = Tensor::from_slice(&[true, false, false, false]).view([1, 4]);
    let (memory, memory_len) = model.core().empty_memory(1, Device::Cpu);
    let out = model.forward_segment(&obs, &starts, &memory, &memory_len);
    // The last step's action reaches the word in its own slots: a gradient path that does not
    // run through the GTrXL memory.
    out.mean.narrow(1, 3, 1).sum(Kind::Float).backward();
    let grad = obs.grad();
    let word_grad = grad
        .narrow(1, 3, 1)
        .narrow(2, fields + 1, 3)
        .abs()
        .sum(Kind::Float);
    assert!(f64::try_from(word_grad).unwrap() > 0.0);
    let empty_grad = grad.narrow(2, fields + 5, 3).abs().sum(Kind::Float);
    assert_eq!(
        f64::try_from(empty_grad).unwrap(),
        0.0,
        "an empty slot's word is ignored"
    );
}
