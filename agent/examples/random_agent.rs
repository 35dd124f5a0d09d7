//! A random agent against any env id on any env servers, printing episode
//! returns: the smallest complete user of `million_env`.
//!
//! ```text
//! cargo run --example random_agent -- --env-server 127.0.0.1:50051 \
//!     [--env-server HOST:PORT ...] [--env Pendulum-v1] [--kwarg env_name=reach-v3 ...] \
//!     [--num-envs 4] [--groups 1] [--episodes 8] [--seed 0]
//! ```
use std::process::ExitCode;

use million_env::{ActionSampler, EnvPool, PoolConfig, parse_kwargs};

struct Args {
    servers: Vec<String>,
    env_id: String,
    kwargs: Vec<String>,
    num_envs: usize,
    groups: usize,
    episodes: usize,
    seed: u64,
}

const USAGE: &str = "usage: random_agent --env-server HOST:PORT [--env-server ...] [--env ID] \
[--kwarg NAME=VALUE ...] [--num-envs N] [--groups G] [--episodes E] [--seed S]";

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        servers: Vec::new(),
        env_id: "Pendulum-v1".into(),
        kwargs: Vec::new(),
        num_envs: 4,
        groups: 1,
        episodes: 8,
        seed: 0,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--help" || flag == "-h" {
            return Err(USAGE.into());
        }
        let value = it
            .next()
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
        let number = |v: &str| v.parse::<usize>().map_err(|e| format!("{flag} {v}: {e}"));
        match flag.as_str() {
            "--env-server" => args.servers.push(value),
            "--env" => args.env_id = value,
            "--kwarg" => args.kwargs.push(value),
            "--num-envs" => args.num_envs = number(&value)?,
            "--groups" => args.groups = number(&value)?,
            "--episodes" => args.episodes = number(&value)?,
            "--seed" => args.seed = number(&value)? as u64,
            _ => return Err(format!("unknown argument {flag}\n{USAGE}")),
        }
    }
    if args.servers.is_empty() {
        return Err(format!("at least one --env-server is needed\n{USAGE}"));
    }
    Ok(args)
}

async fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let mut config = PoolConfig::new(args.servers, args.env_id.clone(), args.num_envs);
    config.kwargs = parse_kwargs(args.kwargs.iter().map(String::as_str))?;
    config.groups = args.groups;
    config.seed = Some(args.seed);
    let mut pool = EnvPool::connect(config).await?;
    let spec = pool.spec().clone();
    println!(
        "{}: {} envs, observation {}, action {}, time limit {}",
        spec.env_id,
        spec.num_envs,
        spec.observation_space,
        spec.action_space,
        spec.max_episode_steps
    );
    let mut sampler = ActionSampler::new(&spec.action_space, args.seed)?;
    pool.reset_all().await?;
    let has_success = spec.info_field("success").is_some();
    let mut returns = vec![0.0; spec.num_envs];
    let mut lengths = vec![0u64; spec.num_envs];
    let mut finished = Vec::new();
    while finished.len() < args.episodes {
        for g in 0..pool.num_groups() {
            let rows = pool.group_envs(g).len();
            pool.send(g, &sampler.sample(rows))?;
        }
        for g in 0..pool.num_groups() {
            let batch = pool.recv(g).await?;
            let success = match (&batch.final_info, has_success) {
                (Some(info), true) => info.f64s("success").ok(),
                _ => None,
            };
            for (row, ended) in batch.ended().into_iter().enumerate() {
                let env = batch.env_offset + row;
                returns[env] += batch.reward[row];
                lengths[env] += 1;
                if !ended {
                    continue;
                }
                let how = if batch.cut[row] {
                    "cut by a server restart"
                } else if batch.terminated[row] {
                    "terminated"
                } else {
                    "truncated"
                };
                let success = success
                    .as_ref()
                    .map(|s| format!(", success {}", s[row]))
                    .unwrap_or_default();
                println!(
                    "env {env:>3}: return {:>10.3} over {:>4} steps ({how}{success})",
                    returns[env], lengths[env]
                );
                finished.push(returns[env]);
                returns[env] = 0.0;
                lengths[env] = 0;
            }
        }
    }
    let mean = finished.iter().sum::<f64>() / finished.len() as f64;
    println!("{} episodes, mean return {mean:.3}", finished.len());
    pool.close().await?;
    Ok(())
}

#[tokio::main]
async fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    match run(args).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("random_agent: {e}");
            ExitCode::FAILURE
        }
    }
}
