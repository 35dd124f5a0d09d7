//! Builds the observation token from named fields in the configured key order.

use crate::config::ObsField;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ObservationError {
    #[error("observation field `{0}` is missing")]
    Missing(String),
    #[error("observation field `{key}` has {got} values, the config says {expected}")]
    WrongSize {
        key: String,
        got: usize,
        expected: usize,
    },
}

/// Appends the token of one step to `out`: the fields of `layout` in order, each looked up by
/// name through `field`.
pub fn append_token<'a>(
    layout: &[ObsField],
    mut field: impl FnMut(&str) -> Option<&'a [f32]>,
    out: &mut Vec<f32>,
) -> Result<(), ObservationError> {
    for f in layout {
        let values = field(&f.key).ok_or_else(|| ObservationError::Missing(f.key.clone()))?;
        if values.len() != f.size {
            return Err(ObservationError::WrongSize {
                key: f.key.clone(),
                got: values.len(),
                expected: f.size,
            });
        }
        out.extend_from_slice(values);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> Vec<ObsField> {
        vec![
            ObsField {
                key: "word".into(),
                size: 2,
            },
            ObsField {
                key: "time".into(),
                size: 1,
            },
        ]
    }

    #[test]
    fn fields_are_concatenated_in_layout_order() {
        let mut out = vec![];
        append_token(
            &layout(),
            |k| match k {
                "time" => Some(&[9.0][..]),
                "word" => Some(&[1.0, 2.0][..]),
                _ => None,
            },
            &mut out,
        )
        .unwrap();
        assert_eq!(out, vec![1.0, 2.0, 9.0]);
    }

    #[test]
    fn missing_or_wrong_sized_fields_are_errors() {
        let mut out = vec![];
        let err = append_token(&layout(), |_| None, &mut out).unwrap_err();
        assert_eq!(err, ObservationError::Missing("word".into()));
        let err = append_token(&layout(), |_| Some(&[1.0][..]), &mut out).unwrap_err();
        assert!(err.to_string().contains("`word` has 1 values"), "{err}");
    }
}
