//! Observation batches from the env pool → the model's inputs: the token `[B, obs]` (the
//! configured fields concatenated in order), the task ids `[B]` and the instruction flags `[B]`.

use million_env::Fields;
use tch::Tensor;

use crate::config::ModelConfig;

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
    fields
        .get(key)
        .ok_or_else(|| TokenError::Missing(key.to_owned()))?
        .to_f32_vec()
        .map_err(|message| TokenError::Decode {
            key: key.to_owned(),
            message,
        })
}

pub fn step_inputs(cfg: &ModelConfig, fields: &Fields) -> Result<StepInputs, TokenError> {
    let rows = fields.rows();
    let dim = cfg.obs_dim();
    let mut token = vec![0f32; rows * dim];
    let mut offset = 0;
    for f in &cfg.observation {
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
        Some(t) => t.to_i64_vec().map_err(|message| TokenError::Decode {
            key: TASK_FIELD.into(),
            message,
        })?,
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
    Ok(StepInputs {
        token: Tensor::from_slice(&token).view([rows as i64, dim as i64]),
        task: Tensor::from_slice(&task),
        instruction: Tensor::from_slice(&instruction),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ObsField;
    use million_env::Tensor as EnvTensor;

    fn cfg() -> ModelConfig {
        ModelConfig {
            observation: vec![
                ObsField {
                    key: "word".into(),
                    size: 2,
                },
                ObsField {
                    key: "phase".into(),
                    size: 1,
                },
            ],
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
        let s = step_inputs(&cfg(), &fields(&[2, 0])).unwrap();
        let token = Vec::<f32>::try_from(s.token.flatten(0, -1)).unwrap();
        assert_eq!(token, vec![1.0, 2.0, 1.0, 3.0, 4.0, 0.0]);
        assert_eq!(Vec::<i64>::try_from(&s.task).unwrap(), vec![2, 0]);
        assert_eq!(
            Vec::<bool>::try_from(&s.instruction).unwrap(),
            vec![true, false]
        );
    }

    #[test]
    fn bad_task_ids_and_missing_fields_are_errors() {
        let err = step_inputs(&cfg(), &fields(&[3, 0])).unwrap_err();
        assert!(err.to_string().contains("task id 3"), "{err}");
        let mut c = cfg();
        c.observation[0].key = "state".into();
        let err = step_inputs(&c, &fields(&[0, 0])).unwrap_err();
        assert!(err.to_string().contains("`state` is missing"), "{err}");
    }
}
