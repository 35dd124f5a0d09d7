//! Training metrics on disk: one JSON object per line (`metrics.jsonl`, easy to
//! read from any language) and TensorBoard event files (`events.out.tfevents.*`),
//! both in the run directory.
//!
//! The TensorBoard writer is small enough to own: an event file is a sequence of
//! TFRecords (length, masked CRC-32C of the length, an `Event` protobuf, masked
//! CRC-32C of the data), and scalars need only three protobuf messages.
//!
//! A resumed run goes on from its checkpoint's step, so the records a killed run wrote
//! after that step describe a future that no longer happens: they move to
//! `metrics.superseded.jsonl` (nothing is lost) and TensorBoard is told to drop them.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use prost::Message;

/// Named scalar values recorded at one agent step.
pub type Scalars = BTreeMap<String, f64>;

/// Writes every record to both `metrics.jsonl` and a TensorBoard event file.
pub struct MetricsWriter {
    jsonl: BufWriter<File>,
    tensorboard: TensorBoardWriter,
}

impl MetricsWriter {
    /// Opens the writers in `run_dir`. `resumed_at`: the agent steps of the checkpoint a
    /// resumed run starts from; the records up to it stay and later ones are superseded.
    /// A new run (None) supersedes every record an earlier run left in `run_dir`.
    pub fn open(run_dir: &Path, resumed_at: Option<u64>) -> Result<Self> {
        std::fs::create_dir_all(run_dir)
            .with_context(|| format!("cannot create run directory {}", run_dir.display()))?;
        let jsonl_path = run_dir.join(crate::run_dir::METRICS_FILE);
        supersede_records_after(&jsonl_path, resumed_at)?;
        let jsonl = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&jsonl_path)
            .with_context(|| format!("cannot open {}", jsonl_path.display()))?;
        let mut tensorboard = TensorBoardWriter::create(run_dir)?;
        tensorboard.restart_after(resumed_at.unwrap_or(0))?;
        Ok(Self {
            jsonl: BufWriter::new(jsonl),
            tensorboard,
        })
    }

    /// Records `scalars` at `step` (agent steps). Non-finite values are kept in
    /// TensorBoard but written as `null` in JSON, which has no NaN.
    pub fn write(&mut self, step: u64, scalars: &Scalars) -> Result<()> {
        let mut record = serde_json::Map::new();
        record.insert(crate::run_dir::STEP_KEY.into(), step.into());
        record.insert(crate::run_dir::WALL_TIME_KEY.into(), wall_time().into());
        for (name, value) in scalars {
            let json =
                serde_json::Number::from_f64(*value).map_or(serde_json::Value::Null, Into::into);
            record.insert(name.clone(), json);
        }
        serde_json::to_writer(&mut self.jsonl, &record)?;
        self.jsonl.write_all(b"\n")?;
        self.jsonl.flush()?;
        self.tensorboard.write_scalars(step, scalars)
    }
}

/// Keeps the records of `path` whose step is at most `kept_through` (none when None) and
/// appends the others, verbatim, to `metrics.superseded.jsonl` beside it. The kept part
/// replaces `path` atomically, so a crash loses no record.
fn supersede_records_after(path: &Path, kept_through: Option<u64>) -> Result<()> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let (mut kept, mut superseded) = (String::new(), String::new());
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        // A line cut short by a kill has no step: it belongs to no checkpoint.
        let step = serde_json::from_str::<serde_json::Value>(line)
            .ok()
            .and_then(|r| r.get(crate::run_dir::STEP_KEY)?.as_u64());
        let keep = matches!((step, kept_through), (Some(s), Some(k)) if s <= k);
        let out = if keep { &mut kept } else { &mut superseded };
        out.push_str(line);
        out.push('\n');
    }
    if superseded.is_empty() {
        return Ok(());
    }
    let aside = path.with_file_name(crate::run_dir::SUPERSEDED_METRICS_FILE);
    OpenOptions::new()
        .create(true)
        .append(true)
        .open(&aside)
        .and_then(|mut f| f.write_all(superseded.as_bytes()))
        .with_context(|| format!("cannot write {}", aside.display()))?;
    crate::run_dir::write_atomically(path, kept.as_bytes())
        .with_context(|| format!("cannot replace {}", path.display()))?;
    tracing::info!(
        lines = superseded.lines().count(),
        file = %aside.display(),
        "metrics after the resumed checkpoint superseded"
    );
    Ok(())
}

/// Appends scalar summaries to a new `events.out.tfevents.<time>.<host>` file.
pub struct TensorBoardWriter {
    file: BufWriter<File>,
    path: PathBuf,
}

impl TensorBoardWriter {
    pub fn create(dir: &Path) -> Result<Self> {
        let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "localhost".into());
        let seconds = wall_time() as u64;
        let path = dir.join(format!(
            "events.out.tfevents.{seconds}.{host}.{}",
            std::process::id()
        ));
        let file =
            File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
        let mut writer = Self {
            file: BufWriter::new(file),
            path,
        };
        writer.write_event(&Event {
            wall_time: wall_time(),
            step: 0,
            file_version: Some("brain.Event:2".into()),
            summary: None,
            session_log: None,
        })?;
        Ok(writer)
    }

    /// Marks a (re)start after `step`: TensorBoard then drops the events at later steps
    /// that earlier files of the run directory hold (a killed run's lost future).
    pub fn restart_after(&mut self, step: u64) -> Result<()> {
        self.write_event(&Event {
            wall_time: wall_time(),
            step: step as i64 + 1,
            file_version: None,
            summary: None,
            session_log: Some(SessionLog {
                status: SESSION_LOG_START,
            }),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn write_scalars(&mut self, step: u64, scalars: &Scalars) -> Result<()> {
        let summary = Summary {
            value: scalars
                .iter()
                .map(|(tag, value)| SummaryValue {
                    tag: tag.clone(),
                    simple_value: *value as f32,
                })
                .collect(),
        };
        self.write_event(&Event {
            wall_time: wall_time(),
            step: step as i64,
            file_version: None,
            summary: Some(summary),
            session_log: None,
        })
    }

    fn write_event(&mut self, event: &Event) -> Result<()> {
        let data = event.encode_to_vec();
        let length = (data.len() as u64).to_le_bytes();
        self.file.write_all(&length)?;
        self.file.write_all(&masked_crc32c(&length).to_le_bytes())?;
        self.file.write_all(&data)?;
        self.file.write_all(&masked_crc32c(&data).to_le_bytes())?;
        self.file.flush()?;
        Ok(())
    }
}

/// TFRecord's checksum: CRC-32C, rotated and offset so that a CRC of data that
/// itself contains CRCs is not trivially zero.
fn masked_crc32c(data: &[u8]) -> u32 {
    let crc = crc32c::crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

fn wall_time() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

// The messages of tensorflow/core/util/event.proto and summary.proto that scalars and
// restarts need, with their field numbers.
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(string, optional, tag = "3")]
    file_version: Option<String>,
    #[prost(message, optional, tag = "5")]
    summary: Option<Summary>,
    #[prost(message, optional, tag = "6")]
    session_log: Option<SessionLog>,
}

/// `SessionLog.SessionStatus.START`: TensorBoard purges later steps of earlier events.
const SESSION_LOG_START: i32 = 1;

#[derive(Clone, PartialEq, prost::Message)]
struct SessionLog {
    #[prost(int32, tag = "1")]
    status: i32,
}

#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, tag = "2")]
    simple_value: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads back the TFRecords of an event file, verifying both checksums.
    fn read_events(path: &Path) -> Vec<Event> {
        let bytes = std::fs::read(path).unwrap();
        let mut events = Vec::new();
        let mut at = 0;
        while at < bytes.len() {
            let length_bytes = &bytes[at..at + 8];
            let length = u64::from_le_bytes(length_bytes.try_into().unwrap()) as usize;
            let length_crc = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap());
            assert_eq!(length_crc, masked_crc32c(length_bytes));
            let data = &bytes[at + 12..at + 12 + length];
            let data_crc = u32::from_le_bytes(
                bytes[at + 12 + length..at + 16 + length]
                    .try_into()
                    .unwrap(),
            );
            assert_eq!(data_crc, masked_crc32c(data));
            events.push(Event::decode(data).unwrap());
            at += 16 + length;
        }
        events
    }

    #[test]
    fn masked_crc_matches_tensorflow() {
        // CRC-32C("123456789") = 0xE3069283, the standard check value; masking it
        // by hand: rotate right 15, add 0xa282ead8.
        let crc: u32 = 0xE306_9283;
        let expected = crc.rotate_right(15).wrapping_add(0xa282_ead8);
        assert_eq!(crc32c::crc32c(b"123456789"), crc);
        assert_eq!(masked_crc32c(b"123456789"), expected);
    }

    #[test]
    fn writes_jsonl_and_tensorboard_records() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = MetricsWriter::open(dir.path(), None).unwrap();
        let scalars: Scalars =
            [("loss".to_string(), 1.5), ("success".to_string(), f64::NAN)].into();
        writer.write(42, &scalars).unwrap();
        let tb_path = writer.tensorboard.path().to_path_buf();
        drop(writer);

        let line = std::fs::read_to_string(dir.path().join("metrics.jsonl")).unwrap();
        let json: serde_json::Value = serde_json::from_str(line.trim()).unwrap();
        assert_eq!(json["step"], 42);
        assert_eq!(json["loss"], 1.5);
        assert!(json["success"].is_null());

        let events = read_events(&tb_path);
        assert_eq!(events.len(), 3);
        assert_eq!(events[0].file_version.as_deref(), Some("brain.Event:2"));
        assert_eq!(
            events[1].session_log.as_ref().unwrap().status,
            SESSION_LOG_START
        );
        let summary = events[2].summary.as_ref().unwrap();
        assert_eq!(events[2].step, 42);
        assert_eq!(summary.value[0].tag, "loss");
        assert_eq!(summary.value[0].simple_value, 1.5);
    }

    fn steps(path: &Path) -> Vec<u64> {
        std::fs::read_to_string(path)
            .unwrap()
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                    .as_u64()
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn resuming_supersedes_the_records_after_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let scalars: Scalars = [("loss".to_string(), 1.0)].into();
        let mut first = MetricsWriter::open(dir.path(), None).unwrap();
        for step in [100, 200, 300, 400] {
            first.write(step, &scalars).unwrap();
        }
        drop(first);
        // Killed after step 400 with its last checkpoint at 200 (and a line cut short).
        let jsonl = dir.path().join("metrics.jsonl");
        let mut f = OpenOptions::new().append(true).open(&jsonl).unwrap();
        f.write_all(b"{\"step\": 5").unwrap();
        drop(f);

        let mut resumed = MetricsWriter::open(dir.path(), Some(200)).unwrap();
        resumed.write(300, &scalars).unwrap();
        let tb_path = resumed.tensorboard.path().to_path_buf();
        drop(resumed);
        assert_eq!(steps(&jsonl), [100, 200, 300]);
        let aside = std::fs::read_to_string(dir.path().join("metrics.superseded.jsonl")).unwrap();
        assert_eq!(
            aside.lines().count(),
            3,
            "300, 400 and the cut line: {aside}"
        );
        let restart = &read_events(&tb_path)[1];
        assert_eq!(restart.step, 201);
        assert_eq!(
            restart.session_log.as_ref().unwrap().status,
            SESSION_LOG_START
        );

        // A new run in the same folder starts a new file and keeps the old one aside.
        drop(MetricsWriter::open(dir.path(), None).unwrap());
        assert_eq!(std::fs::read_to_string(&jsonl).unwrap(), "");
        let aside = std::fs::read_to_string(dir.path().join("metrics.superseded.jsonl")).unwrap();
        assert_eq!(aside.lines().count(), 6);
    }
}
