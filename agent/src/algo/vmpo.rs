//! The V-MPO loss terms for a diagonal Gaussian policy (ALGORITHM.md §4.3–§4.7).

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
