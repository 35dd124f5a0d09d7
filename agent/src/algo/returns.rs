//! n-step bootstrapped returns over a segment (docs/ALGORITHM.md §4.1, no GAE), or λ-returns.
//!
//! With λ = 1 (the original) G_t = r_t + γ G_{t+1}: every target sums the rewards up to the
//! segment's end. With λ < 1, G_t = r_t + γ [(1 − λ) V(s_{t+1}) + λ G_{t+1}] (the λ-return,
//! whose advantage G_t − V(s_t) is GAE(λ)): a step's target leans on the value of the next
//! states instead of on every later reward, which lowers the variance of the advantages.
//!
//! A step whose successor is unknown — the segment's last step, or a step that was truncated
//! (its final observation is not in the segment because the env autoreset) — is not trained;
//! its own value sg(V(s_t)) stands in as the return of the state, so the step before it
//! bootstraps from a state of its own episode. Terminated steps return just their reward.
//! Given one value more than there are steps (`V(s_T)`, the state after the segment), the last
//! step's successor is known: it bootstraps from `V(s_T)` and is trained like the others.

use tch::{Kind, Tensor};

#[derive(Debug)]
pub struct Returns {
    /// `[B, T]` targets G_t (unnormalised).
    pub returns: Tensor,
    /// `[B, T]` bool: steps that enter the losses.
    pub trainable: Tensor,
}

/// `rewards` `[B, T]` and `values` (unnormalised, no gradient) `[B, T]` or `[B, T + 1]` float;
/// `terminated`, `truncated` `[B, T]` bool; `lambda` in [0, 1] (1 = n-step returns).
pub fn bootstrapped_returns(
    rewards: &Tensor,
    values: &Tensor,
    terminated: &Tensor,
    truncated: &Tensor,
    gamma: f64,
    lambda: f64,
) -> Returns {
    let (_, t_len) = rewards.size2().expect("rewards are [B, T]");
    let (_, v_len) = values.size2().expect("values are [B, T] or [B, T + 1]");
    assert!(
        v_len == t_len || v_len == t_len + 1,
        "{v_len} values for {t_len} rewards"
    );
    let values = values.detach();
    let cut = truncated.logical_and(&terminated.logical_not());
    let continues = terminated.logical_not().to_kind(rewards.kind());
    let mut columns = Vec::with_capacity(t_len as usize);
    // The return beyond the last step learned from: V(s_T), or V(s_{T-1}) standing in for it.
    let mut next = values.select(1, v_len - 1);
    let learned = if v_len > t_len { t_len } else { t_len - 1 };
    if learned < t_len {
        columns.push(next.shallow_clone());
    }
    for t in (0..learned).rev() {
        let ahead = if lambda < 1.0 {
            values.select(1, t + 1) * (1.0 - lambda) + &next * lambda
        } else {
            next.shallow_clone()
        };
        let through = rewards.select(1, t) + continues.select(1, t) * ahead * gamma;
        next = values.select(1, t).where_self(&cut.select(1, t), &through);
        columns.push(next.shallow_clone());
    }
    columns.reverse();
    let untrained = Tensor::arange(t_len, (Kind::Int64, rewards.device()))
        .ge(learned)
        .unsqueeze(0);
    Returns {
        returns: Tensor::stack(&columns, 1),
        trainable: cut.logical_or(&untrained).logical_not(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(v: &[f32]) -> Tensor {
        Tensor::from_slice(v).view([1, -1])
    }
    fn flags(v: &[bool]) -> Tensor {
        Tensor::from_slice(v).view([1, -1])
    }
    fn vec(t: &Tensor) -> Vec<f32> {
        Vec::<f32>::try_from(t.flatten(0, -1)).unwrap()
    }

    #[test]
    fn plain_bootstrap_from_the_last_step() {
        // G2 = V2 = 10; G1 = 1 + 0.5·10 = 6; G0 = 2 + 0.5·6 = 5.
        let r = bootstrapped_returns(
            &t(&[2.0, 1.0, 7.0]),
            &t(&[0.0, 0.0, 10.0]),
            &flags(&[false, false, false]),
            &flags(&[false, false, false]),
            0.5,
            1.0,
        );
        assert_eq!(vec(&r.returns), vec![5.0, 6.0, 10.0]);
        assert_eq!(
            Vec::<bool>::try_from(r.trainable.flatten(0, -1)).unwrap(),
            vec![true, true, false]
        );
    }

    #[test]
    fn termination_cuts_and_truncation_bootstraps_from_its_own_value() {
        // Steps: 0 1(terminated) 2 3(truncated) 4 5(last). γ = 0.5.
        // G5 = V5 = 8; G4 = 1 + 0.5·8 = 5; G3 = V3 = 4 (not trained);
        // G2 = 3 + 0.5·4 = 5; G1 = 2 (terminal); G0 = 1 + 0.5·2 = 2.
        let r = bootstrapped_returns(
            &t(&[1.0, 2.0, 3.0, 100.0, 1.0, 100.0]),
            &t(&[50.0, 50.0, 50.0, 4.0, 50.0, 8.0]),
            &flags(&[false, true, false, false, false, false]),
            &flags(&[false, false, false, true, false, false]),
            0.5,
            1.0,
        );
        assert_eq!(vec(&r.returns), vec![2.0, 2.0, 5.0, 4.0, 5.0, 8.0]);
        assert_eq!(
            Vec::<bool>::try_from(r.trainable.flatten(0, -1)).unwrap(),
            vec![true, true, true, false, true, false]
        );
    }

    #[test]
    fn terminated_and_truncated_together_count_as_terminated() {
        let r = bootstrapped_returns(
            &t(&[1.0, 3.0, 0.0]),
            &t(&[9.0, 9.0, 9.0]),
            &flags(&[false, true, false]),
            &flags(&[false, true, false]),
            1.0,
            1.0,
        );
        assert_eq!(vec(&r.returns), vec![4.0, 3.0, 9.0]);
    }

    #[test]
    fn lambda_returns_mix_next_values_and_later_rewards() {
        // V = [1, 2, 10], r = [2, 1, ·], γ = 0.5, λ = 0.5: G2 = V2 = 10;
        // G1 = 1 + 0.5·(0.5·10 + 0.5·10) = 6; G0 = 2 + 0.5·(0.5·V1 + 0.5·G1) = 2 + 0.5·4 = 4.
        let rewards = t(&[2.0, 1.0, 7.0]);
        let values = t(&[1.0, 2.0, 10.0]);
        let none = flags(&[false, false, false]);
        let r = bootstrapped_returns(&rewards, &values, &none, &none, 0.5, 0.5);
        assert_eq!(vec(&r.returns), vec![4.0, 6.0, 10.0]);
        // λ = 0: one-step TD targets r + γ V(s').
        let r = bootstrapped_returns(&rewards, &values, &none, &none, 0.5, 0.0);
        assert_eq!(vec(&r.returns), vec![3.0, 6.0, 10.0]);
    }

    #[test]
    fn a_value_after_the_segment_makes_the_last_step_trainable() {
        // V(s_3) = 10 is given after three steps: G2 = 7 + 0.5·10 = 12, G1 = 1 + 0.5·12 = 7,
        // G0 = 2 + 0.5·7 = 5.5; every step is trained.
        let none = flags(&[false, false, false]);
        let r = bootstrapped_returns(
            &t(&[2.0, 1.0, 7.0]),
            &t(&[0.0, 0.0, 0.0, 10.0]),
            &none,
            &none,
            0.5,
            1.0,
        );
        assert_eq!(vec(&r.returns), vec![5.5, 7.0, 12.0]);
        assert_eq!(
            Vec::<bool>::try_from(r.trainable.flatten(0, -1)).unwrap(),
            vec![true, true, true]
        );
        // A last step that terminated returns its reward; one that was truncated stays untrained
        // on its own value, as anywhere in the segment (the state after it is the next episode's).
        let last = flags(&[false, false, true]);
        let values = t(&[0.0, 0.0, 4.0, 10.0]);
        let rewards = t(&[2.0, 1.0, 7.0]);
        let r = bootstrapped_returns(&rewards, &values, &last, &none, 0.5, 1.0);
        assert_eq!(vec(&r.returns), vec![4.25, 4.5, 7.0]);
        let r = bootstrapped_returns(&rewards, &values, &none, &last, 0.5, 1.0);
        assert_eq!(vec(&r.returns), vec![3.5, 3.0, 4.0]);
        assert_eq!(
            Vec::<bool>::try_from(r.trainable.flatten(0, -1)).unwrap(),
            vec![true, true, false]
        );
    }
}
