//! Reference results of MILLION (docs/ALGORITHM.md §7), drawn on the curves of ML10/ML45 runs.

/// A published final result (no step count given): drawn as a horizontal line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalResult {
    pub label: &'static str,
    pub train: f64,
    pub test: f64,
}

/// One point of a logged reference run: success at `step` agent steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoggedPoint {
    pub step: u64,
    pub train: f64,
    pub test: f64,
}

/// A reference run's logged learning curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoggedRun {
    pub label: &'static str,
    pub points: &'static [LoggedPoint],
}

/// Everything known for one benchmark.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct References {
    pub benchmark: &'static str,
    pub finals: &'static [FinalResult],
    pub logged: &'static [LoggedRun],
}

const fn p(step: u64, train: f64, test: f64) -> LoggedPoint {
    LoggedPoint { step, train, test }
}

const M: u64 = 1_000_000;

pub const ML10: References = References {
    benchmark: "ML10",
    finals: &[
        FinalResult {
            label: "paper V1",
            train: 0.99,
            test: 0.50,
        },
        FinalResult {
            label: "paper V2",
            train: 0.983,
            test: 0.554,
        },
    ],
    logged: &[
        LoggedRun {
            label: "original code, run 0",
            points: &[
                p(10 * M, 0.12, 0.00),
                p(100 * M, 0.21, 0.06),
                p(200 * M, 0.76, 0.31),
                p(400 * M, 0.98, 0.34),
            ],
        },
        LoggedRun {
            label: "original code, run 1",
            points: &[
                p(10 * M, 0.14, 0.00),
                p(100 * M, 0.52, 0.25),
                p(200 * M, 0.92, 0.42),
                p(400 * M, 0.99, 0.45),
            ],
        },
    ],
};

pub const ML45: References = References {
    benchmark: "ML45",
    finals: &[FinalResult {
        label: "paper V1",
        train: 0.95,
        test: 0.48,
    }],
    logged: &[],
};

/// The references of a benchmark name ("ML10", "ML45").
pub fn for_benchmark(benchmark: &str) -> Option<&'static References> {
    match benchmark {
        "ML10" => Some(&ML10),
        "ML45" => Some(&ML45),
        _ => None,
    }
}

impl FinalResult {
    pub fn value(&self, split: &str) -> Option<f64> {
        match split {
            "train" => Some(self.train),
            "test" => Some(self.test),
            _ => None,
        }
    }
}

impl LoggedPoint {
    pub fn value(&self, split: &str) -> Option<f64> {
        match split {
            "train" => Some(self.train),
            "test" => Some(self.test),
            _ => None,
        }
    }
}
