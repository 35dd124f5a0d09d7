//! Observation batches and info batches: typed views of `proto::Observation`
//! and `proto::Info`, with a leading batch dimension on every tensor.
use crate::proto;
use crate::space::{InfoFieldSpec, Space};
use crate::tensor::{DType, Tensor};

/// Name of the only field of a flat (non-Dict) observation in `Fields`.
pub const FLAT_FIELD: &str = "observation";

/// An observation batch: a tensor for a flat space, or named parts for a Dict.
#[derive(Clone, Debug, PartialEq)]
pub enum Observation {
    Tensor(Tensor),
    Dict(Vec<(String, Observation)>),
}

/// Named leaf tensors of an observation batch, in the space's order. A flat
/// observation is the single field `FLAT_FIELD`; nested Dict entries are named
/// by their path joined with `/`.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Fields(pub Vec<(String, Tensor)>);

impl Fields {
    pub fn get(&self, name: &str) -> Option<&Tensor> {
        self.0.iter().find(|(n, _)| n == name).map(|(_, t)| t)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.0.iter().map(|(n, _)| n.as_str())
    }

    pub fn iter(&self) -> impl Iterator<Item = (&str, &Tensor)> {
        self.0.iter().map(|(n, t)| (n.as_str(), t))
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Rows of the batch (0 when there are no fields).
    pub fn rows(&self) -> usize {
        self.0.first().map_or(0, |(_, t)| t.rows())
    }

    /// Every field's row `row` converted to f32 and laid end to end: the flat
    /// vector an MLP takes.
    pub fn row_f32(&self, row: usize) -> Result<Vec<f32>, String> {
        let mut out = Vec::new();
        for (_, t) in &self.0 {
            out.extend(t.slice_rows(row..row + 1)?.to_f32_vec()?);
        }
        Ok(out)
    }
}

impl Observation {
    pub fn from_proto(obs: proto::Observation) -> Result<Self, String> {
        use proto::observation::Kind;
        match obs.kind.ok_or("observation without a kind")? {
            Kind::Tensor(t) => Ok(Observation::Tensor(Tensor::from_proto(t)?)),
            Kind::Dict(d) => Ok(Observation::Dict(
                d.entries
                    .into_iter()
                    .map(|e| {
                        let value = e.value.ok_or_else(|| {
                            format!("observation entry {} without a value", e.name)
                        })?;
                        Ok((e.name, Observation::from_proto(value)?))
                    })
                    .collect::<Result<_, String>>()?,
            )),
        }
    }

    pub fn to_proto(&self) -> proto::Observation {
        use proto::observation::Kind;
        let kind = match self {
            Observation::Tensor(t) => Kind::Tensor(t.to_proto()),
            Observation::Dict(entries) => Kind::Dict(proto::ObservationDict {
                entries: entries
                    .iter()
                    .map(|(name, o)| proto::NamedObservation {
                        name: name.clone(),
                        value: Some(o.to_proto()),
                    })
                    .collect(),
            }),
        };
        proto::Observation { kind: Some(kind) }
    }

    /// Zero observations (all leaves zero) for `rows` environments of `space`.
    pub fn zeros(space: &Space, rows: usize) -> Self {
        match space {
            Space::Dict(entries) => Observation::Dict(
                entries
                    .iter()
                    .map(|(n, s)| (n.clone(), Observation::zeros(s, rows)))
                    .collect(),
            ),
            leaf => {
                let (dtype, shape) = leaf.leaf_layout().expect("non-Dict spaces have a layout");
                Observation::Tensor(Tensor::zeros(dtype, batched(rows, &shape)))
            }
        }
    }

    /// Rows of the batch (of its first leaf).
    pub fn rows(&self) -> usize {
        match self {
            Observation::Tensor(t) => t.rows(),
            Observation::Dict(entries) => entries.first().map_or(0, |(_, o)| o.rows()),
        }
    }

    pub fn fields(&self) -> Fields {
        let mut out = Vec::new();
        self.collect_fields("", &mut out);
        Fields(out)
    }

    fn collect_fields(&self, prefix: &str, out: &mut Vec<(String, Tensor)>) {
        match self {
            Observation::Tensor(t) => {
                let name = if prefix.is_empty() {
                    FLAT_FIELD
                } else {
                    prefix
                };
                out.push((name.to_owned(), t.clone()));
            }
            Observation::Dict(entries) => {
                for (name, o) in entries {
                    let path = if prefix.is_empty() {
                        name.clone()
                    } else {
                        format!("{prefix}/{name}")
                    };
                    o.collect_fields(&path, out);
                }
            }
        }
    }

    /// Rows `range` of every leaf; shares payloads.
    pub fn slice_rows(&self, range: std::ops::Range<usize>) -> Result<Self, String> {
        self.map_leaves(&mut |t| t.slice_rows(range.clone()))
    }

    fn map_leaves(
        &self,
        f: &mut impl FnMut(&Tensor) -> Result<Tensor, String>,
    ) -> Result<Self, String> {
        Ok(match self {
            Observation::Tensor(t) => Observation::Tensor(f(t)?),
            Observation::Dict(entries) => Observation::Dict(
                entries
                    .iter()
                    .map(|(n, o)| Ok((n.clone(), o.map_leaves(f)?)))
                    .collect::<Result<_, String>>()?,
            ),
        })
    }

    /// Stacks batches of the same structure along the batch dimension.
    pub fn concat_rows(parts: &[Observation]) -> Result<Self, String> {
        let first = parts.first().ok_or("nothing to concatenate")?;
        if parts.len() == 1 {
            return Ok(first.clone());
        }
        match first {
            Observation::Tensor(_) => {
                let leaves = parts
                    .iter()
                    .map(|p| match p {
                        Observation::Tensor(t) => Ok(t.clone()),
                        Observation::Dict(_) => Err("mixing Dict and flat observations".to_owned()),
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                Ok(Observation::Tensor(Tensor::concat_rows(&leaves)?))
            }
            Observation::Dict(entries) => {
                let mut out = Vec::with_capacity(entries.len());
                for (i, (name, _)) in entries.iter().enumerate() {
                    let column = parts
                        .iter()
                        .map(|p| match p {
                            Observation::Dict(e) if e.get(i).is_some_and(|(n, _)| n == name) => {
                                Ok(e[i].1.clone())
                            }
                            _ => Err(format!("observation parts disagree on entry {name}")),
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    out.push((name.clone(), Observation::concat_rows(&column)?));
                }
                Ok(Observation::Dict(out))
            }
        }
    }

    /// Checks that this batch of `rows` environments has the structure, dtypes
    /// and shapes `space` declares, and that Box values lie within its finite
    /// bounds. The error names the offending leaf.
    pub fn conforms_to(&self, space: &Space, rows: usize) -> Result<(), String> {
        self.conforms_at(space, rows, FLAT_FIELD, true)
    }

    /// Like `conforms_to` for structure, dtypes and shapes only, not values
    /// (e.g. final observations, whose rows that did not end are zeros).
    pub fn conforms_to_layout(&self, space: &Space, rows: usize) -> Result<(), String> {
        self.conforms_at(space, rows, FLAT_FIELD, false)
    }

    fn conforms_at(
        &self,
        space: &Space,
        rows: usize,
        path: &str,
        values: bool,
    ) -> Result<(), String> {
        match (self, space) {
            (Observation::Dict(entries), Space::Dict(spaces)) => {
                let got: Vec<&str> = entries.iter().map(|(n, _)| n.as_str()).collect();
                let want: Vec<&str> = spaces.iter().map(|(n, _)| n.as_str()).collect();
                if got != want {
                    return Err(format!(
                        "{path}: Dict entries {got:?}, the space declares {want:?}"
                    ));
                }
                for ((name, o), (_, s)) in entries.iter().zip(spaces) {
                    o.conforms_at(s, rows, name, values)?;
                }
                Ok(())
            }
            (Observation::Tensor(t), leaf) if !matches!(leaf, Space::Dict(_)) => {
                let (dtype, shape) = leaf.leaf_layout().expect("non-Dict spaces have a layout");
                let want_shape = batched(rows, &shape);
                if t.dtype() != dtype || t.shape() != want_shape.as_slice() {
                    return Err(format!(
                        "{path}: got {} {:?}, the space declares {dtype} {want_shape:?}",
                        t.dtype(),
                        t.shape()
                    ));
                }
                if values {
                    value_in_space(t, leaf).map_err(|e| format!("{path}: {e}"))?;
                }
                Ok(())
            }
            _ => Err(format!(
                "{path}: observation structure does not match the space"
            )),
        }
    }
}

fn value_in_space(t: &Tensor, space: &Space) -> Result<(), String> {
    match space {
        Space::Box(b) => {
            let values = t.to_f64_vec()?;
            let per_row = b.low.len();
            for (i, v) in values.iter().enumerate() {
                let (lo, hi) = (b.low[i % per_row], b.high[i % per_row]);
                if v.is_nan() {
                    return Err(format!("element {i} is NaN"));
                }
                // Bounds are checked where they are finite; float32 rounding of a
                // float64 bound is tolerated.
                let tol = 1e-6 * (1.0 + lo.abs().max(hi.abs()).min(1e30));
                if (lo.is_finite() && *v < lo - tol) || (hi.is_finite() && *v > hi + tol) {
                    return Err(format!(
                        "element {i} (row {}, index {}) = {v} lies outside [{lo}, {hi}]",
                        i / per_row.max(1),
                        i % per_row.max(1)
                    ));
                }
            }
            Ok(())
        }
        Space::Discrete { n, start } => {
            for v in t.to_i64_vec()? {
                if v < *start || v >= start + n {
                    return Err(format!("{v} outside Discrete [{start}, {})", start + n));
                }
            }
            Ok(())
        }
        Space::MultiBinary { .. } => {
            if t.to_i64_vec()?.iter().any(|v| *v != 0 && *v != 1) {
                return Err("MultiBinary value other than 0/1".into());
            }
            Ok(())
        }
        Space::MultiDiscrete { nvec, start, .. } => {
            for (i, v) in t.to_i64_vec()?.into_iter().enumerate() {
                let j = i % nvec.len();
                if v < start[j] || v >= start[j] + nvec[j] {
                    return Err(format!("element {i} = {v} outside its MultiDiscrete range"));
                }
            }
            Ok(())
        }
        Space::Dict(_) => Err("Dict space where a leaf was expected".into()),
    }
}

pub(crate) fn batched(rows: usize, shape: &[usize]) -> Vec<usize> {
    let mut s = Vec::with_capacity(shape.len() + 1);
    s.push(rows);
    s.extend_from_slice(shape);
    s
}

/// One info field of a batch.
#[derive(Clone, Debug, PartialEq)]
pub struct InfoField {
    pub name: String,
    /// `[rows, *field shape]`; rows not set this step hold the dtype's zero.
    pub value: Tensor,
    /// One per row: true where the environment set the field.
    pub present: Vec<bool>,
}

/// The info of a batch: one entry per declared field.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct InfoBatch(pub Vec<InfoField>);

impl InfoBatch {
    pub fn from_proto(info: proto::Info) -> Result<Self, String> {
        info.entries
            .into_iter()
            .map(|e| {
                let value = Tensor::from_proto(
                    e.value
                        .ok_or_else(|| format!("info entry {} without a value", e.name))?,
                )
                .map_err(|err| format!("info entry {}: {err}", e.name))?;
                if value.shape().is_empty() || e.present.len() != value.rows() {
                    return Err(format!(
                        "info entry {}: {} present flags for a value of shape {:?}",
                        e.name,
                        e.present.len(),
                        value.shape()
                    ));
                }
                Ok(InfoField {
                    name: e.name,
                    value,
                    present: e.present,
                })
            })
            .collect::<Result<_, _>>()
            .map(InfoBatch)
    }

    /// A batch where no field is present (zeros), e.g. for rows that did not end.
    pub fn absent(fields: &[InfoFieldSpec], rows: usize) -> Self {
        InfoBatch(
            fields
                .iter()
                .map(|f| InfoField {
                    name: f.name.clone(),
                    value: Tensor::zeros(f.dtype, batched(rows, &f.shape)),
                    present: vec![false; rows],
                })
                .collect(),
        )
    }

    pub fn get(&self, name: &str) -> Option<&InfoField> {
        self.0.iter().find(|f| f.name == name)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.0.iter().map(|f| f.name.as_str())
    }

    /// Per-row values of a numeric field converted to f64.
    pub fn f64s(&self, name: &str) -> Result<Vec<f64>, String> {
        self.get(name)
            .ok_or_else(|| format!("no info field {name}"))?
            .value
            .to_f64_vec()
    }

    pub fn bools(&self, name: &str) -> Result<Vec<bool>, String> {
        self.get(name)
            .ok_or_else(|| format!("no info field {name}"))?
            .value
            .to_bool_vec()
    }

    pub fn strings(&self, name: &str) -> Result<&[String], String> {
        let f = self
            .get(name)
            .ok_or_else(|| format!("no info field {name}"))?;
        if f.value.dtype() != DType::String {
            return Err(format!(
                "info field {name} is {}, not string",
                f.value.dtype()
            ));
        }
        Ok(f.value.strings())
    }

    /// Stacks row batches field by field, in the order of `fields`; a part that
    /// lacks a declared field contributes absent rows.
    pub fn concat_rows(
        parts: &[(usize, Option<&InfoBatch>)],
        fields: &[InfoFieldSpec],
    ) -> Result<Self, String> {
        let mut out = Vec::with_capacity(fields.len());
        for spec in fields {
            let mut values = Vec::with_capacity(parts.len());
            let mut present = Vec::new();
            for (rows, part) in parts {
                match part.and_then(|p| p.get(&spec.name)) {
                    Some(f) => {
                        values.push(f.value.clone());
                        present.extend_from_slice(&f.present);
                    }
                    None => {
                        values.push(Tensor::zeros(spec.dtype, batched(*rows, &spec.shape)));
                        present.extend(std::iter::repeat_n(false, *rows));
                    }
                }
            }
            out.push(InfoField {
                name: spec.name.clone(),
                value: Tensor::concat_rows(&values)
                    .map_err(|e| format!("info field {}: {e}", spec.name))?,
                present,
            });
        }
        Ok(InfoBatch(out))
    }

    /// Checks the batch against the declared fields: every field sent, no other,
    /// each `[rows, *shape]` of the declared dtype with one present flag per row.
    pub fn conforms_to(&self, fields: &[InfoFieldSpec], rows: usize) -> Result<(), String> {
        let mut got: Vec<&str> = self.names().collect();
        let mut want: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
        got.sort_unstable();
        want.sort_unstable();
        if got != want {
            return Err(format!("info fields {got:?}, the spec declares {want:?}"));
        }
        for spec in fields {
            let f = self.get(&spec.name).expect("names compared above");
            let want_shape = batched(rows, &spec.shape);
            if f.value.dtype() != spec.dtype || f.value.shape() != want_shape.as_slice() {
                return Err(format!(
                    "info field {}: got {} {:?}, declared {} {want_shape:?}",
                    spec.name,
                    f.value.dtype(),
                    f.value.shape(),
                    spec.dtype
                ));
            }
            if f.present.len() != rows {
                return Err(format!(
                    "info field {}: {} present flags for {rows} rows",
                    spec.name,
                    f.present.len()
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::BoxSpace;

    fn dict_space() -> Space {
        Space::Dict(vec![
            (
                "state".into(),
                Space::Box(BoxSpace {
                    shape: vec![2],
                    dtype: DType::Float64,
                    low: vec![-1.0, f64::NEG_INFINITY],
                    high: vec![1.0, f64::INFINITY],
                }),
            ),
            ("phase".into(), Space::Discrete { n: 3, start: 0 }),
        ])
    }

    #[test]
    fn zeros_conform_and_flatten_to_named_fields() {
        let obs = Observation::zeros(&dict_space(), 4);
        obs.conforms_to(&dict_space(), 4).unwrap();
        let fields = obs.fields();
        assert_eq!(fields.names().collect::<Vec<_>>(), ["state", "phase"]);
        assert_eq!(fields.get("state").unwrap().shape(), &[4, 2]);
        assert_eq!(fields.row_f32(3).unwrap(), vec![0.0, 0.0, 0.0]);
        assert!(obs.conforms_to(&dict_space(), 3).is_err());
    }

    #[test]
    fn out_of_bounds_values_are_named() {
        let bad = Observation::Dict(vec![
            (
                "state".into(),
                Observation::Tensor(Tensor::from_f64(vec![1, 2], &[1.5, 1e9]).unwrap()),
            ),
            (
                "phase".into(),
                Observation::Tensor(Tensor::from_i64(vec![1], &[0]).unwrap()),
            ),
        ]);
        let err = bad.conforms_to(&dict_space(), 1).unwrap_err();
        assert!(err.contains("state") && err.contains("1.5"), "{err}");
    }

    #[test]
    fn concatenates_dicts_and_infos() {
        let a = Observation::zeros(&dict_space(), 1);
        let b = Observation::zeros(&dict_space(), 2);
        let joined = Observation::concat_rows(&[a, b]).unwrap();
        assert_eq!(joined.rows(), 3);
        let spec = vec![InfoFieldSpec {
            name: "success".into(),
            dtype: DType::Bool,
            shape: vec![],
            description: String::new(),
        }];
        let some = InfoBatch(vec![InfoField {
            name: "success".into(),
            value: Tensor::from_bool(vec![2], &[true, false]).unwrap(),
            present: vec![true, true],
        }]);
        let info = InfoBatch::concat_rows(&[(2, Some(&some)), (1, None)], &spec).unwrap();
        info.conforms_to(&spec, 3).unwrap();
        assert_eq!(info.bools("success").unwrap(), vec![true, false, false]);
        assert_eq!(
            info.get("success").unwrap().present,
            vec![true, true, false]
        );
    }
}
