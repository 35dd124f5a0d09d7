//! Typed, validated replies of one handle: `ResetResponse` and `StepResponse`.
use crate::error::EnvError;
use crate::observation::{InfoBatch, Observation};
use crate::proto;

/// Reply of a reset: one row per reset environment, in request order.
#[derive(Clone, Debug, PartialEq)]
pub struct ResetResult {
    pub obs: Observation,
    pub info: InfoBatch,
    /// The env index of each row.
    pub env_indices: Vec<u32>,
}

/// Reply of a step: one row per environment of the handle, in index order.
#[derive(Clone, Debug, PartialEq)]
pub struct StepResult {
    pub obs: Observation,
    pub reward: Vec<f64>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    pub info: InfoBatch,
    /// SAME_STEP only, when a row ended: all rows, the ended ones holding the
    /// ending observation.
    pub final_obs: Option<Observation>,
    pub final_info: Option<InfoBatch>,
}

impl StepResult {
    pub fn rows(&self) -> usize {
        self.reward.len()
    }

    /// True for rows whose episode ended at this step (either flag).
    pub fn ended(&self) -> Vec<bool> {
        self.terminated
            .iter()
            .zip(&self.truncated)
            .map(|(a, b)| *a || *b)
            .collect()
    }
}

impl ResetResult {
    pub fn from_proto(addr: &str, r: proto::ResetResponse) -> Result<Self, EnvError> {
        let bad = |d: String| EnvError::protocol(addr, format!("reset reply: {d}"));
        let obs =
            Observation::from_proto(r.observation.ok_or_else(|| bad("no observation".into()))?)
                .map_err(bad)?;
        let info = InfoBatch::from_proto(r.info.unwrap_or_default()).map_err(bad)?;
        if obs.rows() != r.env_indices.len() {
            return Err(bad(format!(
                "{} observation rows for {} env indices",
                obs.rows(),
                r.env_indices.len()
            )));
        }
        check_info_rows(&info, obs.rows()).map_err(bad)?;
        Ok(ResetResult {
            obs,
            info,
            env_indices: r.env_indices,
        })
    }
}

impl StepResult {
    pub fn from_proto(addr: &str, r: proto::StepResponse) -> Result<Self, EnvError> {
        let bad = |d: String| EnvError::protocol(addr, format!("step reply: {d}"));
        let obs =
            Observation::from_proto(r.observation.ok_or_else(|| bad("no observation".into()))?)
                .map_err(bad)?;
        let rows = obs.rows();
        if r.reward.len() != rows || r.terminated.len() != rows || r.truncated.len() != rows {
            return Err(bad(format!(
                "{rows} observation rows but {} rewards, {} terminated, {} truncated",
                r.reward.len(),
                r.terminated.len(),
                r.truncated.len()
            )));
        }
        let info = InfoBatch::from_proto(r.info.unwrap_or_default()).map_err(bad)?;
        check_info_rows(&info, rows).map_err(bad)?;
        let final_obs = r
            .final_observation
            .map(Observation::from_proto)
            .transpose()
            .map_err(bad)?;
        if let Some(f) = &final_obs
            && f.rows() != rows
        {
            return Err(bad(format!(
                "{} final observation rows for {rows} envs",
                f.rows()
            )));
        }
        let final_info = r
            .final_info
            .map(InfoBatch::from_proto)
            .transpose()
            .map_err(bad)?;
        if let Some(fi) = &final_info {
            check_info_rows(fi, rows).map_err(bad)?;
        }
        Ok(StepResult {
            obs,
            reward: r.reward,
            terminated: r.terminated,
            truncated: r.truncated,
            info,
            final_obs,
            final_info,
        })
    }
}

fn check_info_rows(info: &InfoBatch, rows: usize) -> Result<(), String> {
    for f in &info.0 {
        if f.value.rows() != rows {
            return Err(format!(
                "info field {} has {} rows, the reply {rows}",
                f.name,
                f.value.rows()
            ));
        }
    }
    Ok(())
}
