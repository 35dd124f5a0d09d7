//! The V-MPO loss terms for a diagonal Gaussian policy (docs/ALGORITHM.md §4.3–§4.7).

use tch::{Kind, Tensor};

/// Indices of the `⌊fraction · N⌋` valid steps with the largest advantages (N = valid steps),
/// or `None` when that is zero.
pub fn top_advantages(advantages: &Tensor, valid: &Tensor, fraction: f64) -> Option<Tensor> {
    let n = valid.sum(Kind::Int64).int64_value(&[]);
    let k = (n as f64 * fraction).floor() as i64;
    if k == 0 {
        return None;
    }
    let scores = advantages
        .detach()
        .masked_fill(&valid.logical_not(), f64::NEG_INFINITY);
    let (_, idx) = scores.topk(k, 0, true, false);
    Some(idx)
}

/// ψ = softmax(Â / η) over the selected steps, without gradient.
pub fn psi_weights(top_advantages: &Tensor, eta: &Tensor) -> Tensor {
    (top_advantages.detach() / eta.detach())
        .softmax(0, Kind::Float)
        .detach()
}

/// The E-step of one update (§4.3–§4.4): the steps the policy loss learns from, their
/// weights ψ (summing to 1) and the temperature loss L_η.
pub struct EStep {
    pub idx: Tensor,
    pub psi: Tensor,
    pub temperature_loss: Tensor,
}

/// The paper's E-step: the top `fraction` of all valid steps by advantage, ψ a softmax over
/// them. `None` when no step is kept.
pub fn e_step(
    advantages: &Tensor,
    valid: &Tensor,
    fraction: f64,
    eta: &Tensor,
    eps_eta: f64,
) -> Option<EStep> {
    let idx = top_advantages(advantages, valid, fraction)?;
    let top = advantages.index_select(0, &idx);
    Some(EStep {
        psi: psi_weights(&top, eta),
        temperature_loss: temperature_loss(eta, &top, eps_eta),
        idx,
    })
}

/// The E-step done apart for each task [S]: the top `fraction` of each task's valid steps,
/// ψ a softmax within the task scaled by the task's share k_task / k of the kept steps, and
/// L_η = Σ_task (k_task / k) L_η,task. With one task it is [`e_step`]. Over a batch of several
/// tasks, the paper's E-step ranks every task's advantages together, so a task whose
/// advantages are smaller than the others' (one without successes yet) loses its share of
/// the top half and of ψ; here every task keeps the share of the batch it was sampled with.
pub fn e_step_per_task(
    advantages: &Tensor,
    valid: &Tensor,
    task: &Tensor,
    fraction: f64,
    eta: &Tensor,
    eps_eta: f64,
) -> Option<EStep> {
    let present: std::collections::BTreeSet<i64> =
        Vec::<i64>::try_from(task.masked_select(valid).to_device(tch::Device::Cpu))
            .expect("task ids")
            .into_iter()
            .collect();
    let steps: Vec<EStep> = present
        .into_iter()
        .filter_map(|id| {
            e_step(
                advantages,
                &valid.logical_and(&task.eq(id)),
                fraction,
                eta,
                eps_eta,
            )
        })
        .collect();
    let kept: Vec<f64> = steps.iter().map(|e| e.idx.size()[0] as f64).collect();
    let total: f64 = kept.iter().sum();
    if total == 0.0 {
        return None;
    }
    let idx = Tensor::cat(&steps.iter().map(|e| &e.idx).collect::<Vec<_>>(), 0);
    let psi = Tensor::cat(
        &steps
            .iter()
            .zip(&kept)
            .map(|(e, k)| &e.psi * (k / total))
            .collect::<Vec<_>>(),
        0,
    );
    let temperature_loss = steps
        .iter()
        .zip(&kept)
        .map(|(e, k)| &e.temperature_loss * (k / total))
        .reduce(|a, b| a + b)
        .expect("at least one task");
    Some(EStep {
        idx,
        psi,
        temperature_loss,
    })
}

/// Σ of ψ over each task's kept steps, `[num_tasks]`: how much of the policy loss each task
/// gets (with the per-task E-step, its share of the kept steps).
pub fn psi_mass_per_task(psi: &Tensor, selected_tasks: &Tensor, num_tasks: i64) -> Tensor {
    Tensor::zeros([num_tasks], (Kind::Float, psi.device())).scatter_add(
        0,
        selected_tasks,
        &psi.to_kind(Kind::Float),
    )
}

/// L_η = η ε_η + η [logsumexp(Â / η) − log k]; the gradient reaches η only.
pub fn temperature_loss(eta: &Tensor, top_advantages: &Tensor, eps_eta: f64) -> Tensor {
    let k = top_advantages.size()[0] as f64;
    let adv = top_advantages.detach();
    eta * eps_eta + eta * ((&adv / eta).logsumexp(0, false) - k.ln())
}

/// C_μ = ½ Σ_i (μ_i − μ_old,i)² / σ²_old,i per step `[N]`.
pub fn kl_mean(mean: &Tensor, old_mean: &Tensor, old_std: &Tensor) -> Tensor {
    ((mean - old_mean).square() / old_std.square()).sum_dim_intlist(-1, false, Kind::Float) * 0.5
}

/// C_Σ = ½ Σ_i [σ²_old,i / σ²_i − 1 + log(σ²_i / σ²_old,i)] per step `[N]`.
pub fn kl_std(std: &Tensor, old_std: &Tensor) -> Tensor {
    let ratio = old_std.square() / std.square();
    (&ratio - 1.0 - ratio.log()).sum_dim_intlist(-1, false, Kind::Float) * 0.5
}

/// mean over valid steps of α(ε − sg C) + sg(α) C.
pub fn multiplier_loss(alpha: &Tensor, kl: &Tensor, eps: f64, valid: &Tensor) -> Tensor {
    let w = valid.to_kind(Kind::Float);
    let n = w.sum(Kind::Float).clamp_min(1.0);
    let per_step = alpha * (-kl.detach() + eps) + alpha.detach() * kl;
    (per_step * w).sum(Kind::Float) / n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(t: &Tensor) -> Vec<f64> {
        Vec::<f64>::try_from(t.to_kind(Kind::Double).flatten(0, -1)).unwrap()
    }

    #[test]
    fn top_half_ignores_invalid_steps_and_keeps_the_largest() {
        // Valid: 3, -1, 5, 0 (N = 4, k = 2) → steps 3 and 0 (advantages 5 and 3).
        let adv = Tensor::from_slice(&[3.0f32, 100.0, -1.0, 5.0, 0.0]);
        let valid = Tensor::from_slice(&[true, false, true, true, true]);
        let idx = top_advantages(&adv, &valid, 0.5).unwrap();
        let mut got = Vec::<i64>::try_from(idx).unwrap();
        got.sort();
        assert_eq!(got, vec![0, 3]);
        let one = Tensor::from_slice(&[true, false, false, false, false]);
        assert!(top_advantages(&adv, &one, 0.5).is_none());
    }

    #[test]
    fn psi_is_the_softmax_over_the_top_half() {
        // Â = [5, 3], η = 2: ψ = e^{2.5} / (e^{2.5} + e^{1.5}) = 1 / (1 + e^{-1}).
        let psi = psi_weights(&Tensor::from_slice(&[5.0f32, 3.0]), &Tensor::from(2.0f32));
        let p0 = 1.0 / (1.0 + (-1.0f64).exp());
        let got = v(&psi);
        assert!((got[0] - p0).abs() < 1e-6 && (got[1] - (1.0 - p0)).abs() < 1e-6);
    }

    #[test]
    fn psi_mass_sums_each_tasks_weights() {
        let psi = Tensor::from_slice(&[0.5f32, 0.3, 0.2]);
        let tasks = Tensor::from_slice(&[2i64, 0, 2]);
        let got = v(&psi_mass_per_task(&psi, &tasks, 3));
        for (g, want) in got.iter().zip([0.3, 0.0, 0.7]) {
            assert!((g - want).abs() < 1e-6, "{got:?}");
        }
    }

    #[test]
    fn per_task_e_step_keeps_each_tasks_top_half_and_share() {
        // Task 0 has large advantages, task 1 small ones: the paper's E-step keeps only
        // task 0's steps; per task, each keeps its own top half (k = 2 each of 4).
        let adv = Tensor::from_slice(&[9.0f32, 8.0, 7.0, 6.0, 0.3, 0.2, 0.1, 0.0]);
        let task = Tensor::from_slice(&[0i64, 0, 0, 0, 1, 1, 1, 1]);
        let valid = Tensor::from_slice(&[true; 8]);
        let eta = Tensor::from(1.0f32);
        let whole = e_step(&adv, &valid, 0.5, &eta, 0.1).unwrap();
        let mass = v(&psi_mass_per_task(
            &whole.psi,
            &task.index_select(0, &whole.idx),
            2,
        ));
        assert!((mass[0] - 1.0).abs() < 1e-6 && mass[1].abs() < 1e-6);

        let per = e_step_per_task(&adv, &valid, &task, 0.5, &eta, 0.1).unwrap();
        let mut idx = Vec::<i64>::try_from(&per.idx).unwrap();
        idx.sort();
        assert_eq!(idx, vec![0, 1, 4, 5]);
        let mass = v(&psi_mass_per_task(
            &per.psi,
            &task.index_select(0, &per.idx),
            2,
        ));
        assert!((mass[0] - 0.5).abs() < 1e-6 && (mass[1] - 0.5).abs() < 1e-6);
        // L_η is the share-weighted mean of each task's own temperature loss.
        let l0 = temperature_loss(&eta, &Tensor::from_slice(&[9.0f32, 8.0]), 0.1);
        let l1 = temperature_loss(&eta, &Tensor::from_slice(&[0.3f32, 0.2]), 0.1);
        let want = (l0.double_value(&[]) + l1.double_value(&[])) / 2.0;
        assert!((per.temperature_loss.double_value(&[]) - want).abs() < 1e-5);
        // With one task the per-task E-step is the paper's.
        let one = Tensor::zeros([8], (Kind::Int64, tch::Device::Cpu));
        let a = e_step(&adv, &valid, 0.5, &eta, 0.1).unwrap();
        let b = e_step_per_task(&adv, &valid, &one, 0.5, &eta, 0.1).unwrap();
        assert_eq!(v(&a.psi), v(&b.psi));
        assert!(e_step_per_task(&adv, &valid.logical_not(), &task, 0.5, &eta, 0.1).is_none());
    }

    #[test]
    fn temperature_loss_matches_the_formula_and_its_gradient() {
        // η = 2, Â = [5, 3], ε = 0.1: L = 0.2 + 2 (log(e^{2.5} + e^{1.5}) − log 2).
        let eta = Tensor::from(2.0f64).set_requires_grad(true);
        let adv = Tensor::from_slice(&[5.0f64, 3.0]);
        let loss = temperature_loss(&eta, &adv, 0.1);
        let lse = (2.5f64.exp() + 1.5f64.exp()).ln();
        assert!((loss.double_value(&[]) - (0.2 + 2.0 * (lse - 2f64.ln()))).abs() < 1e-12);
        loss.backward();
        // dL/dη = ε + lse − log 2 − Σ ψ Â / η.
        let p0 = 1.0 / (1.0 + (-1.0f64).exp());
        let expected = 0.1 + lse - 2f64.ln() - (p0 * 5.0 + (1.0 - p0) * 3.0) / 2.0;
        assert!((eta.grad().double_value(&[]) - expected).abs() < 1e-12);
    }

    #[test]
    fn both_kl_terms_match_the_gaussian_closed_form() {
        let mean = Tensor::from_slice(&[0.5f64, -0.2]).view([1, 2]);
        let old_mean = Tensor::from_slice(&[0.1f64, 0.3]).view([1, 2]);
        let std = Tensor::from_slice(&[0.4f64, 1.5]).view([1, 2]);
        let old_std = Tensor::from_slice(&[0.8f64, 1.0]).view([1, 2]);
        // KL(N(μo, σo) ‖ N(μ, σo)) = Σ (μ − μo)² / (2 σo²)
        let cm = 0.4f64.powi(2) / (2.0 * 0.64) + 0.5f64.powi(2) / 2.0;
        // KL(N(μo, σo) ‖ N(μo, σ)) = Σ log(σ/σo) + σo²/(2σ²) − ½
        let cs =
            (0.4f64 / 0.8).ln() + 0.64 / (2.0 * 0.16) - 0.5 + (1.5f64).ln() + 1.0 / (2.0 * 2.25)
                - 0.5;
        assert!((v(&kl_mean(&mean, &old_mean, &old_std))[0] - cm).abs() < 1e-6);
        assert!((v(&kl_std(&std, &old_std))[0] - cs).abs() < 1e-6);
        assert!(v(&kl_std(&old_std, &old_std))[0].abs() < 1e-12);
    }

    #[test]
    fn multiplier_loss_pushes_alpha_by_the_constraint_and_the_policy_by_alpha() {
        let alpha = Tensor::from(2.0f32).set_requires_grad(true);
        let kl = Tensor::from_slice(&[0.3f32, 0.1, 9.0]).set_requires_grad(true);
        let valid = Tensor::from_slice(&[true, true, false]);
        let loss = multiplier_loss(&alpha, &kl, 0.05, &valid);
        // mean over valid of 2(0.05 − C) + 2C = 0.1 (value); dL/dα = 0.05 − mean C = −0.15.
        assert!((loss.double_value(&[]) - 0.1).abs() < 1e-6);
        loss.backward();
        assert!((alpha.grad().double_value(&[]) + 0.15).abs() < 1e-6);
        assert_eq!(v(&kl.grad()), vec![1.0, 1.0, 0.0]);
    }
}
