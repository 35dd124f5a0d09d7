//! Observation batches from the env pool → the model's inputs: the token `[B, obs]` (the
//! configured fields concatenated in order, then the instruction slots when
//! `model.instruction_words` > 0, then the env's `goal` info when `model.goal_prediction` is
//! on), the task ids `[B]` and the instruction flags `[B]`.

use million_env::{Fields, InfoBatch};
use tch::Tensor;

use crate::config::{GOAL_INFO, ModelConfig};
use crate::train::instruction_slots::InstructionSlots;

#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("observation field `{0}` is missing (the config's model.observation names it)")]
    Missing(String),
    #[error(
        "observation field `{key}` has {got} values per env, model.observation says {expected}"
    )]
    WrongSize {
        key: String,
        got: usize,
        expected: usize,
    },
    #[error("observation field `{key}`: {message}")]
    Decode { key: String, message: String },
    #[error("task id {id} is outside model.num_tasks = {num_tasks}")]
    TaskId { id: i64, num_tasks: usize },
    #[error(
        "model.goal_prediction needs the env's `{GOAL_INFO}` info ({width} values per env) on \
         every step: {message}"
    )]
    Goal { width: usize, message: String },
}

/// Model inputs of one step of a group.
#[derive(Debug)]
pub struct StepInputs {
    pub token: Tensor,
    pub task: Tensor,
    pub instruction: Tensor,
}

/// Name of the task-id field; observations without it are task 0 (one value head row).
pub const TASK_FIELD: &str = "task_id";
/// Name of the phase field (1 = instruction phase); without it every step is a trial step.
pub const PHASE_FIELD: &str = "phase";

fn field_f32(fields: &Fields, key: &str) -> Result<Vec<f32>, TokenError> {
    decode_field(fields, key, |t| t.to_f32_vec())
}

/// An integer field of one value per row (task ids, one-hot fields).
fn field_i64(fields: &Fields, key: &str) -> Result<Vec<i64>, TokenError> {
    let values = decode_field(fields, key, |t| t.to_i64_vec())?;
    if values.len() != fields.rows() {
        return Err(TokenError::WrongSize {
            key: key.to_owned(),
            got: values.len() / fields.rows().max(1),
            expected: 1,
        });
    }
    Ok(values)
}

fn decode_field<T>(
    fields: &Fields,
    key: &str,
    decode: impl FnOnce(&million_env::Tensor) -> Result<Vec<T>, String>,
) -> Result<Vec<T>, TokenError> {
    let tensor = fields
        .get(key)
        .ok_or_else(|| TokenError::Missing(key.to_owned()))?;
    decode(tensor).map_err(|message| TokenError::Decode {
        key: key.to_owned(),
        message,
    })
}

/// Builds the model's inputs step after step for a fixed set of env rows; it keeps the
/// instruction slots, the one part of a token that depends on earlier steps.
#[derive(Debug)]
pub struct TokenBuilder {
    /// The slots and where the word lies in a token (offset, width); None without slots.
    slots: Option<(InstructionSlots, (usize, usize))>,
}

impl TokenBuilder {
    pub fn new(cfg: &ModelConfig, rows: usize) -> Self {
        // Config validation refuses slots without a word field, so the span is there.
        let slots = match cfg.word_span() {
            Some(span) if cfg.instruction_words > 0 => Some((
                InstructionSlots::new(rows, cfg.instruction_words, span.1),
                span,
            )),
            _ => None,
        };
        Self { slots }
    }

    /// The inputs of one step; `episode_start[r]` marks row r's first step of an episode.
    /// `info` is the step's info, read only for `model.goal_prediction`'s goal.
    pub fn step_inputs(
        &mut self,
        cfg: &ModelConfig,
        fields: &Fields,
        info: Option<&InfoBatch>,
        episode_start: &[bool],
    ) -> Result<StepInputs, TokenError> {
        let (mut token, task, instruction) = fields_token(cfg, fields)?;
        if let Some((offset, width)) = cfg.goal_span() {
            let goals = goal_rows(info, fields.rows(), width)?;
            for (row, goal) in token
                .chunks_exact_mut(cfg.obs_dim())
                .zip(goals.chunks_exact(width))
            {
                row[offset..offset + width].copy_from_slice(goal);
            }
        }
        if let Some((slots, (offset, width))) = &mut self.slots {
            // The word is in the token already: read it back rather than decode the field a
            // second time.
            let (dim, from, offset, width) = (cfg.obs_dim(), cfg.fields_dim(), *offset, *width);
            let words: Vec<f32> = token
                .chunks_exact(dim)
                .flat_map(|row| &row[offset..offset + width])
                .copied()
                .collect();
            slots.observe(&words, &instruction, episode_start);
            let len = cfg.instruction_dim();
            for (r, row) in token.chunks_exact_mut(dim).enumerate() {
                row[from..from + len].copy_from_slice(slots.row(r));
            }
        }
        let rows = fields.rows() as i64;
        Ok(StepInputs {
            token: Tensor::from_slice(&token).view([rows, cfg.obs_dim() as i64]),
            task: Tensor::from_slice(&task),
            instruction: Tensor::from_slice(&instruction),
        })
    }
}

type RowsToken = (Vec<f32>, Vec<i64>, Vec<bool>);

/// The env's goal of every row, `rows × width` values, from a step's info.
fn goal_rows(info: Option<&InfoBatch>, rows: usize, width: usize) -> Result<Vec<f32>, TokenError> {
    let err = |message: String| TokenError::Goal { width, message };
    let field = info
        .and_then(|i| i.get(GOAL_INFO))
        .ok_or_else(|| err("the env sends none".into()))?;
    if let Some(r) = field.present.iter().position(|p| !p) {
        return Err(err(format!("row {r} lacks it")));
    }
    let values: Vec<f32> = field
        .value
        .to_f64_vec()
        .map_err(err)?
        .into_iter()
        .map(|v| v as f32)
        .collect();
    if values.len() != rows * width {
        return Err(err(format!("{} values for {rows} rows", values.len())));
    }
    Ok(values)
}

/// Writes a one-integer-per-row field as one-hot vectors of `f.size` entries at `offset` of
/// each token row (`model.observation`'s `one_hot`).
fn write_one_hot(
    fields: &Fields,
    f: &crate::config::ObsField,
    token: &mut [f32],
    dim: usize,
    offset: usize,
) -> Result<(), TokenError> {
    let ids = field_i64(fields, &f.key)?;
    for (r, &id) in ids.iter().enumerate() {
        if id < 0 || id as usize >= f.size {
            return Err(TokenError::Decode {
                key: f.key.clone(),
                message: format!("{id} is outside the one-hot field's {} entries", f.size),
            });
        }
        token[r * dim + offset + id as usize] = 1.0;
    }
    Ok(())
}

/// The token rows with the configured fields written (the slots left zero), task ids and
/// instruction flags.
fn fields_token(cfg: &ModelConfig, fields: &Fields) -> Result<RowsToken, TokenError> {
    let rows = fields.rows();
    let dim = cfg.obs_dim();
    let mut token = vec![0f32; rows * dim];
    let mut offset = 0;
    for f in &cfg.observation {
        if f.one_hot {
            write_one_hot(fields, f, &mut token, dim, offset)?;
            offset += f.size;
            continue;
        }
        let values = field_f32(fields, &f.key)?;
        if values.len() != rows * f.size {
            return Err(TokenError::WrongSize {
                key: f.key.clone(),
                got: values.len() / rows.max(1),
                expected: f.size,
            });
        }
        for r in 0..rows {
            token[r * dim + offset..r * dim + offset + f.size]
                .copy_from_slice(&values[r * f.size..(r + 1) * f.size]);
        }
        offset += f.size;
    }
    let task = match fields.get(TASK_FIELD) {
        Some(_) => field_i64(fields, TASK_FIELD)?,
        None => vec![0; rows],
    };
    if let Some(&id) = task
        .iter()
        .find(|&&id| id < 0 || id as usize >= cfg.num_tasks)
    {
        return Err(TokenError::TaskId {
            id,
            num_tasks: cfg.num_tasks,
        });
    }
    let instruction: Vec<bool> = match fields.get(PHASE_FIELD) {
        Some(_) => field_f32(fields, PHASE_FIELD)?
            .iter()
            .map(|&p| p > 0.5)
            .collect(),
        None => vec![false; rows],
    };
    Ok((token, task, instruction))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ObsField;
    use million_env::Tensor as EnvTensor;

    fn cfg() -> ModelConfig {
        ModelConfig {
            observation: vec![ObsField::new("word", 2), ObsField::new("phase", 1)],
            num_tasks: 3,
            ..ModelConfig::default()
        }
    }

    fn fields(task: &[i64]) -> Fields {
        Fields(vec![
            (
                "phase".into(),
                EnvTensor::from_f32(vec![2, 1], &[1.0, 0.0]).unwrap(),
            ),
            (
                "word".into(),
                EnvTensor::from_f64(vec![2, 2], &[1.0, 2.0, 3.0, 4.0]).unwrap(),
            ),
            (
                "task_id".into(),
                EnvTensor::from_i64(vec![2], task).unwrap(),
            ),
        ])
    }

    #[test]
    fn tokens_follow_the_configured_order_and_convert_dtypes() {
        let s = TokenBuilder::new(&cfg(), 2)
            .step_inputs(&cfg(), &fields(&[2, 0]), None, &[true, true])
            .unwrap();
        let token = Vec::<f32>::try_from(s.token.flatten(0, -1)).unwrap();
        assert_eq!(token, vec![1.0, 2.0, 1.0, 3.0, 4.0, 0.0]);
        assert_eq!(Vec::<i64>::try_from(&s.task).unwrap(), vec![2, 0]);
        assert_eq!(
            Vec::<bool>::try_from(&s.instruction).unwrap(),
            vec![true, false]
        );
    }

    #[test]
    fn a_one_hot_field_writes_a_one_at_its_integer() {
        let mut c = cfg();
        c.observation.push(ObsField {
            one_hot: true,
            ..ObsField::new("task_id", 3)
        });
        let step = |c: &ModelConfig, task: &[i64]| {
            TokenBuilder::new(c, 2).step_inputs(c, &fields(task), None, &[true, true])
        };
        let token = Vec::<f32>::try_from(step(&c, &[2, 0]).unwrap().token.flatten(0, -1)).unwrap();
        #[rustfmt::skip]
        assert_eq!(token, vec![
            1.0, 2.0, 1.0, /* task 2 */ 0.0, 0.0, 1.0,
            3.0, 4.0, 0.0, /* task 0 */ 1.0, 0.0, 0.0,
        ]);
        c.observation[2].size = 2;
        let err = step(&c, &[2, 0]).unwrap_err();
        assert!(
            err.to_string()
                .contains("outside the one-hot field's 2 entries"),
            "{err}"
        );
    }

    #[test]
    fn bad_task_ids_and_missing_fields_are_errors() {
        let step = |c: &ModelConfig, task: &[i64]| {
            TokenBuilder::new(c, 2).step_inputs(c, &fields(task), None, &[true, true])
        };
        let err = step(&cfg(), &[3, 0]).unwrap_err();
        assert!(err.to_string().contains("task id 3"), "{err}");
        let mut c = cfg();
        c.observation[0].key = "state".into();
        let err = step(&c, &[0, 0]).unwrap_err();
        assert!(err.to_string().contains("`state` is missing"), "{err}");
    }

    #[test]
    fn instruction_slots_follow_the_fields() {
        let c = ModelConfig {
            instruction_words: 2,
            ..cfg()
        };
        let mut b = TokenBuilder::new(&c, 2);
        let first = b
            .step_inputs(&c, &fields(&[0, 0]), None, &[true, true])
            .unwrap();
        let token = Vec::<f32>::try_from(first.token.flatten(0, -1)).unwrap();
        // Row 0 is in an instruction phase: its word joins slot 0; row 1 is in a trial.
        #[rustfmt::skip]
        assert_eq!(token, vec![
            1.0, 2.0, 1.0, /* slots */ 1.0, 1.0, 2.0, 0.0, 0.0, 0.0,
            3.0, 4.0, 0.0, /* slots */ 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ]);
    }

    fn goal_info(values: &[f64], present: [bool; 2]) -> InfoBatch {
        InfoBatch(vec![million_env::InfoField {
            name: GOAL_INFO.into(),
            value: EnvTensor::from_f64(vec![2, 3], values).unwrap(),
            present: present.to_vec(),
        }])
    }

    #[test]
    fn the_goal_to_predict_follows_the_slots_and_is_required_when_asked() {
        let c = ModelConfig {
            instruction_words: 1,
            goal_prediction: crate::config::GoalPrediction::Probe,
            ..cfg()
        };
        let goals = [0.1, 0.6, 0.2, -0.1, 0.7, 0.05];
        let info = goal_info(&goals, [true, true]);
        let s = TokenBuilder::new(&c, 2)
            .step_inputs(&c, &fields(&[0, 0]), Some(&info), &[true, true])
            .unwrap();
        let token = Vec::<f32>::try_from(s.token.flatten(0, -1)).unwrap();
        #[rustfmt::skip]
        assert_eq!(token, vec![
            1.0, 2.0, 1.0, /* slot */ 1.0, 1.0, 2.0, /* goal */ 0.1, 0.6, 0.2,
            3.0, 4.0, 0.0, /* slot */ 0.0, 0.0, 0.0, /* goal */ -0.1, 0.7, 0.05,
        ]);
        assert_eq!(c.goal_span(), Some((6, 3)));
        let step = |info: Option<&InfoBatch>| {
            TokenBuilder::new(&c, 2)
                .step_inputs(&c, &fields(&[0, 0]), info, &[true, true])
                .unwrap_err()
                .to_string()
        };
        assert!(step(None).contains("the env sends none"), "{}", step(None));
        let missing = step(Some(&goal_info(&goals, [true, false])));
        assert!(missing.contains("row 1 lacks it"), "{missing}");
    }
}
