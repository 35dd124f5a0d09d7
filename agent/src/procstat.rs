//! CPU time and peak memory of this process and its child processes (the local env servers),
//! read from Linux's `/proc`. `bench train` samples the children while they run, because they
//! are gone (and their `/proc` entries with them) once training stops them.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use serde::Serialize;

/// What one process used: CPU seconds (user + system) and peak resident memory.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ProcessUsage {
    pub pid: u32,
    pub command: String,
    pub cpu_s: f64,
    pub peak_rss_mb: f64,
}

/// Usage of `pid` now; None once it has exited (or off Linux).
pub fn usage(pid: u32) -> Option<ProcessUsage> {
    let (command, fields) = stat(pid)?;
    // utime and stime are fields 14 and 15 of stat, i.e. 12 and 13 after the state field.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let peak_kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .split_whitespace()
        .next()?
        .parse()
        .ok()?;
    Some(ProcessUsage {
        pid,
        command,
        cpu_s: ticks / clock_ticks_per_s(),
        peak_rss_mb: peak_kb / 1024.0,
    })
}

fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf only reads a constant of the system.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 { t as f64 } else { 100.0 }
}

/// `/proc/PID/stat`: the command, and the fields after it (the state first). The command is
/// in parentheses and may hold spaces, so the fields start after the last `") "`.
fn stat(pid: u32) -> Option<(String, Vec<String>)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let (head, rest) = text.rsplit_once(") ")?;
    let command = head.split_once(" (")?.1.to_owned();
    Some((
        command,
        rest.split_whitespace().map(str::to_owned).collect(),
    ))
}

/// The pids whose parent is `parent`.
pub fn children(parent: u32) -> Vec<u32> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&pid| {
            // The parent pid is the field after the state.
            stat(pid).and_then(|(_, fields)| fields.get(1)?.parse::<u32>().ok()) == Some(parent)
        })
        .collect()
}

/// Samples this process's children every `period` on a thread, keeping each one's last
/// reading, so their totals survive their exit.
pub struct ChildSampler {
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<BTreeMap<u32, ProcessUsage>>>,
    thread: Option<JoinHandle<()>>,
}

impl ChildSampler {
    pub fn start(period: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Mutex::new(BTreeMap::new()));
        let thread = {
            let (stop, seen) = (stop.clone(), seen.clone());
            std::thread::spawn(move || {
                let me = std::process::id();
                while !stop.load(Ordering::Relaxed) {
                    let now: Vec<ProcessUsage> =
                        children(me).into_iter().filter_map(usage).collect();
                    let mut seen = seen.lock().expect("sampler lock");
                    for u in now {
                        seen.insert(u.pid, u);
                    }
                    drop(seen);
                    std::thread::sleep(period);
                }
            })
        };
        Self {
            stop,
            seen,
            thread: Some(thread),
        }
    }

    /// Stops sampling; every child seen, with its last reading.
    pub fn finish(mut self) -> Vec<ProcessUsage> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.seen
            .lock()
            .expect("sampler lock")
            .values()
            .cloned()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_this_process_and_a_child() {
        let me = usage(std::process::id()).expect("own /proc entry");
        assert!(me.peak_rss_mb > 1.0 && me.cpu_s >= 0.0);
        let mut child = std::process::Command::new("sleep")
            .arg("5")
            .spawn()
            .unwrap();
        let sampler = ChildSampler::start(Duration::from_millis(20));
        std::thread::sleep(Duration::from_millis(200));
        let seen = sampler.finish();
        child.kill().unwrap();
        child.wait().unwrap();
        let sleep = seen
            .iter()
            .find(|u| u.pid == child.id())
            .expect("child sampled");
        assert_eq!(sleep.command, "sleep");
        assert!(sleep.peak_rss_mb > 0.0);
    }
}
