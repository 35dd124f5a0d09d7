//! Throughput of `EnvPool` with random actions: env steps per second.
//!
//! ```text
//! cargo run --release -p million-env --example pool_bench -- \
//!     --env-server 127.0.0.1:50051 [--env-server ...] --env Meta-World/MT1 \
//!     --kwarg env_name=reach-v3 --kwarg seed=1 --num-envs 16 [--groups 1] [--steps 500]
//! ```
use std::time::Instant;

use million_env::{ActionSampler, EnvPool, PoolConfig, parse_kwargs};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut servers = Vec::new();
    let mut env_id = "Meta-World/MT1".to_owned();
    let mut kwargs = Vec::new();
    let (mut num_envs, mut groups, mut steps) = (16usize, 1usize, 500usize);
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--env-server" => servers.push(value),
            "--env" => env_id = value,
            "--kwarg" => kwargs.push(value),
            "--num-envs" => num_envs = value.parse()?,
            "--groups" => groups = value.parse()?,
            "--steps" => steps = value.parse()?,
            _ => return Err(format!("unknown argument {flag}").into()),
        }
    }
    if servers.is_empty() {
        return Err("at least one --env-server is needed".into());
    }
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async move {
        let n_servers = servers.len();
        let mut config = PoolConfig::new(servers, env_id.clone(), num_envs);
        config.kwargs = parse_kwargs(kwargs.iter().map(String::as_str))?;
        config.groups = groups;
        config.seed = Some(0);
        let mut pool = EnvPool::connect(config).await?;
        let mut sampler = ActionSampler::new(&pool.spec().action_space, 0)?;
        pool.reset_all().await?;
        let sizes: Vec<usize> = (0..groups).map(|g| pool.group_envs(g).len()).collect();
        // Warm-up, then the timed run: every group always has a step in flight.
        let mut round = async |pool: &mut EnvPool, rounds: usize| -> million_env::Result<()> {
            for (g, &rows) in sizes.iter().enumerate() {
                pool.send(g, &sampler.sample(rows))?;
            }
            for r in 0..rounds {
                for (g, &rows) in sizes.iter().enumerate() {
                    pool.recv(g).await?;
                    if r + 1 < rounds {
                        pool.send(g, &sampler.sample(rows))?;
                    }
                }
            }
            Ok(())
        };
        round(&mut pool, 20).await?;
        let start = Instant::now();
        round(&mut pool, steps).await?;
        let secs = start.elapsed().as_secs_f64();
        let env_steps = (steps * num_envs) as f64;
        println!(
            "{env_id}: {num_envs} envs, {groups} group(s), {n_servers} server(s): \
             {:.0} env steps/s ({:.0} batch steps/s, {:.2} ms per batch step)",
            env_steps / secs,
            steps as f64 / secs,
            1e3 * secs / steps as f64
        );
        pool.close().await?;
        Ok(())
    })
}
