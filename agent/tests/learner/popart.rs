//! Pop-Art: statistics by hand, outputs preserved by the update.

use million::config::PopArtConfig;
use million::model::popart::PopArt;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

fn popart(cfg: PopArtConfig) -> (VarStore, PopArt) {
    tch::manual_seed(11);
    let mut vs = VarStore::new(Device::Cpu);
    let p = PopArt::new(vs.root() / "popart", 4, 3, cfg);
    vs.double();
    (vs, p)
}

fn values(p: &PopArt, h: &Tensor, task: &Tensor) -> Vec<f64> {
    let v = tch::no_grad(|| p.unnormalise(&p.normalised(h, task), task));
    Vec::<f64>::try_from(v).unwrap()
}

#[test]
fn update_matches_hand_computed_statistics_and_preserves_outputs() {
    let (_vs, mut p) = popart(PopArtConfig {
        beta: 0.5,
        ..Default::default()
    });
    let h = Tensor::randn([6, 4], (Kind::Double, Device::Cpu));
    let task = Tensor::from_slice(&[0i64, 0, 1, 1, 1, 0]);
    let before = values(&p, &h, &task);
    // Task 0 targets 2 and 4 (the 100 is masked out); task 1 targets 10, 20, 30; task 2 none.
    let g = Tensor::from_slice(&[2.0f64, 4.0, 10.0, 20.0, 30.0, 100.0]);
    let valid = Tensor::from_slice(&[true, true, true, true, true, false]);
    let summary = p.update(&g, &task, &valid);
    assert_eq!(summary.tasks_updated, 2);
    // μ0 = 0.5·0 + 0.5·3 = 1.5; ν0 = 0.5·1 + 0.5·10 = 5.5; σ0 = sqrt(5.5 − 2.25)
    // μ1 = 0.5·20 = 10; ν1 = 0.5 + 0.5·(1400/3); σ1 = sqrt(ν1 − 100)
    let mu = Vec::<f64>::try_from(p.mu()).unwrap();
    let sigma = Vec::<f64>::try_from(p.sigma()).unwrap();
    let nu1: f64 = 0.5 + 0.5 * (1400.0 / 3.0);
    assert_eq!(mu, vec![1.5, 10.0, 0.0]);
    assert!((sigma[0] - 3.25f64.sqrt()).abs() < 1e-12);
    assert!((sigma[1] - (nu1 - 100.0).sqrt()).abs() < 1e-12);
    assert_eq!(sigma[2], 1.0);
    let after = values(&p, &h, &task);
    for (a, b) in before.iter().zip(&after) {
        assert!((a - b).abs() < 1e-12 * a.abs().max(1.0), "{a} vs {b}");
    }
    // The normalised targets use the new statistics.
    let norm = Vec::<f64>::try_from(p.normalise_targets(&g, &task)).unwrap();
    assert!((norm[0] - (2.0 - 1.5) / sigma[0]).abs() < 1e-12);
}

#[test]
fn sigma_is_clipped_to_its_range() {
    let (_vs, mut p) = popart(PopArtConfig {
        beta: 1.0,
        sigma_min: 0.5,
        sigma_max: 2.0,
        ..Default::default()
    });
    let task = Tensor::from_slice(&[0i64, 1, 1]);
    // Task 0: one target → variance 0 → σ = 0.5. Task 1: 0 and 100 → σ = 50 → 2.
    p.update(
        &Tensor::from_slice(&[7.0f64, 0.0, 100.0]),
        &task,
        &Tensor::from_slice(&[true, true, true]),
    );
    let sigma = Vec::<f64>::try_from(p.sigma()).unwrap();
    assert_eq!(sigma, vec![0.5, 2.0, 1.0]);
}

#[test]
fn disabled_popart_keeps_an_unnormalised_head() {
    let (_vs, mut p) = popart(PopArtConfig {
        enabled: false,
        ..Default::default()
    });
    let h = Tensor::randn([3, 4], (Kind::Double, Device::Cpu));
    let task = Tensor::from_slice(&[0i64, 1, 2]);
    let before = values(&p, &h, &task);
    p.update(
        &Tensor::from_slice(&[50.0f64, 60.0, 70.0]),
        &task,
        &Tensor::from_slice(&[true, true, true]),
    );
    assert_eq!(values(&p, &h, &task), before);
    let g = Tensor::from_slice(&[50.0f64, 60.0, 70.0]);
    assert_eq!(
        Vec::<f64>::try_from(p.normalise_targets(&g, &task)).unwrap(),
        vec![50.0, 60.0, 70.0]
    );
}
