//! Typed keyword arguments (`proto::Value`), and parsing them from the command line.
use std::collections::{BTreeMap, HashMap};
use std::fmt;

use crate::proto;
use crate::proto::value::Kind;

/// A keyword-argument value: a small JSON-like union, never a pickle.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    Bool(bool),
    Int(i64),
    Float(f64),
    String(String),
    List(Vec<Value>),
    Map(BTreeMap<String, Value>),
}

/// Keyword arguments by name, in a stable order.
pub type Kwargs = BTreeMap<String, Value>;

impl Value {
    pub fn to_proto(&self) -> proto::Value {
        let kind = match self {
            Value::Bool(b) => Kind::BoolValue(*b),
            Value::Int(i) => Kind::IntValue(*i),
            Value::Float(f) => Kind::FloatValue(*f),
            Value::String(s) => Kind::StringValue(s.clone()),
            Value::List(items) => Kind::ListValue(proto::ValueList {
                values: items.iter().map(Value::to_proto).collect(),
            }),
            Value::Map(map) => Kind::MapValue(proto::ValueMap {
                entries: kwargs_to_proto(map),
            }),
        };
        proto::Value { kind: Some(kind) }
    }

    pub fn from_proto(value: &proto::Value) -> Result<Self, String> {
        Ok(match value.kind.as_ref().ok_or("value without a kind")? {
            Kind::BoolValue(b) => Value::Bool(*b),
            Kind::IntValue(i) => Value::Int(*i),
            Kind::FloatValue(f) => Value::Float(*f),
            Kind::StringValue(s) => Value::String(s.clone()),
            Kind::ListValue(l) => Value::List(
                l.values
                    .iter()
                    .map(Value::from_proto)
                    .collect::<Result<_, _>>()?,
            ),
            Kind::MapValue(m) => Value::Map(kwargs_from_proto(&m.entries)?),
        })
    }

    fn from_json(json: serde_json::Value) -> Result<Self, String> {
        Ok(match json {
            serde_json::Value::Bool(b) => Value::Bool(b),
            serde_json::Value::Number(n) => match n.as_i64() {
                Some(i) => Value::Int(i),
                None => Value::Float(n.as_f64().ok_or("number out of range")?),
            },
            serde_json::Value::String(s) => Value::String(s),
            serde_json::Value::Array(items) => Value::List(
                items
                    .into_iter()
                    .map(Value::from_json)
                    .collect::<Result<_, _>>()?,
            ),
            serde_json::Value::Object(map) => Value::Map(
                map.into_iter()
                    .map(|(k, v)| Ok((k, Value::from_json(v)?)))
                    .collect::<Result<_, String>>()?,
            ),
            serde_json::Value::Null => return Err("null is not a kwarg value".into()),
        })
    }
}

impl From<&str> for Value {
    fn from(s: &str) -> Self {
        Value::String(s.to_owned())
    }
}
impl From<String> for Value {
    fn from(s: String) -> Self {
        Value::String(s)
    }
}
impl From<i64> for Value {
    fn from(i: i64) -> Self {
        Value::Int(i)
    }
}
impl From<f64> for Value {
    fn from(f: f64) -> Self {
        Value::Float(f)
    }
}
impl From<bool> for Value {
    fn from(b: bool) -> Self {
        Value::Bool(b)
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(b) => write!(f, "{b}"),
            Value::Int(i) => write!(f, "{i}"),
            Value::Float(x) => write!(f, "{x}"),
            Value::String(s) => write!(f, "{s:?}"),
            Value::List(items) => {
                f.write_str("[")?;
                for (i, v) in items.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{v}")?;
                }
                f.write_str("]")
            }
            Value::Map(map) => {
                f.write_str("{")?;
                for (i, (k, v)) in map.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{k:?}: {v}")?;
                }
                f.write_str("}")
            }
        }
    }
}

pub fn kwargs_to_proto(kwargs: &Kwargs) -> HashMap<String, proto::Value> {
    kwargs
        .iter()
        .map(|(k, v)| (k.clone(), v.to_proto()))
        .collect()
}

pub fn kwargs_from_proto(kwargs: &HashMap<String, proto::Value>) -> Result<Kwargs, String> {
    kwargs
        .iter()
        .map(|(k, v)| Ok((k.clone(), Value::from_proto(v)?)))
        .collect()
}

/// Parses `name=value` as given on a command line. The value is read as JSON
/// when it is JSON (`3`, `0.5`, `true`, `[1, 2]`, `"x"`), else as a plain string,
/// so `env_name=reach-v3` needs no quotes.
pub fn parse_kwarg(arg: &str) -> Result<(String, Value), String> {
    let (name, raw) = arg
        .split_once('=')
        .ok_or_else(|| format!("kwarg {arg:?} is not of the form name=value"))?;
    let name = name.trim();
    if name.is_empty() {
        return Err(format!("kwarg {arg:?} has an empty name"));
    }
    let value = match serde_json::from_str::<serde_json::Value>(raw) {
        Ok(json) => Value::from_json(json).map_err(|e| format!("kwarg {name}: {e}"))?,
        Err(_) => Value::String(raw.to_owned()),
    };
    Ok((name.to_owned(), value))
}

/// Parses several `name=value` arguments; a repeated name is an error.
pub fn parse_kwargs<'a>(args: impl IntoIterator<Item = &'a str>) -> Result<Kwargs, String> {
    let mut out = Kwargs::new();
    for arg in args {
        let (name, value) = parse_kwarg(arg)?;
        if out.insert(name.clone(), value).is_some() {
            return Err(format!("kwarg {name} given twice"));
        }
    }
    Ok(out)
}

/// Parses an env case as the contract runners write it: `ID` or
/// `ID:key=value,key=value` (the same syntax as pytest's `--env`).
pub fn parse_env_case(text: &str) -> Result<(String, Kwargs), String> {
    let (env_id, rest) = text.split_once(':').unwrap_or((text, ""));
    let env_id = env_id.trim();
    if env_id.is_empty() {
        return Err(format!("env case {text:?} has no env id"));
    }
    let kwargs = parse_kwargs(rest.split(',').map(str::trim).filter(|s| !s.is_empty()))
        .map_err(|e| format!("env case {text:?}: {e}"))?;
    Ok((env_id.to_owned(), kwargs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_env_cases_like_the_pytest_runner() {
        let (id, kw) = parse_env_case("Meta-World/MT1:env_name=reach-v3,seed=1").unwrap();
        assert_eq!(id, "Meta-World/MT1");
        assert_eq!(kw["env_name"], Value::from("reach-v3"));
        assert_eq!(kw["seed"], Value::Int(1));
        assert_eq!(
            parse_env_case("CartPole-v1").unwrap(),
            ("CartPole-v1".into(), Kwargs::new())
        );
        assert!(parse_env_case(":x=1").is_err());
        assert!(parse_env_case("A-v0:novalue").is_err());
    }

    #[test]
    fn parses_json_values_and_bare_strings() {
        let kw = parse_kwargs([
            "env_name=reach-v3",
            "n=3",
            "x=0.5",
            "flag=true",
            "l=[1, \"a\"]",
        ])
        .unwrap();
        assert_eq!(kw["env_name"], Value::from("reach-v3"));
        assert_eq!(kw["n"], Value::Int(3));
        assert_eq!(kw["x"], Value::Float(0.5));
        assert_eq!(kw["flag"], Value::Bool(true));
        assert_eq!(kw["l"], Value::List(vec![Value::Int(1), Value::from("a")]));
        assert!(parse_kwargs(["a=1", "a=2"]).unwrap_err().contains("twice"));
        assert!(parse_kwarg("novalue").is_err());
        assert!(parse_kwarg("x=null").is_err());
    }

    #[test]
    fn round_trips_through_proto() {
        let mut inner = Kwargs::new();
        inner.insert("k".into(), Value::Float(1.5));
        let v = Value::List(vec![Value::Map(inner), Value::Bool(false)]);
        assert_eq!(Value::from_proto(&v.to_proto()).unwrap(), v);
    }
}
