#!/usr/bin/env bash
# `make test-docker`: the env servers and the agent in containers, for real.
#
#   docker/test-docker.sh [MILLION_BINARY]     (default target/release/million)
#
# 1. Local base images (docker/make-base-images.sh: debootstrap + docker import; no
#    registry is reachable here) and the host's wheels (docker/offline.sh env-server).
# 2. The env-server image from docker/env-server.Dockerfile (built from source), and the
#    agent image from the binary `make build` made on the host, packed with the part of
#    libtorch it needs (docker/agent-bundle.sh, docker/agent-runtime.Dockerfile). Users
#    build docker/agent.Dockerfile, which makes the same bundle from source; CI does not
#    build it (a cold Rust + torch build in a container would take most of CI's time).
# 3. docker/compose.yaml with 2 env-server replicas and the agent on the compose
#    project's private network; the agent gets one name, env-server:50051, and trains
#    configs/quickstart.toml. Mid-run one env-server container is killed (docker kill)
#    and, later, the agent container is restarted (it resumes from its checkpoint).
# 4. Checks: the agent used both replicas, survived the kill (its envs rebuilt on a live
#    replica), resumed after the restart, and stopped at the target success with a final
#    evaluation; exit code 0.
set -euo pipefail
cd "$(dirname "$0")/.."
binary=${1:-target/release/million}
CACHE=${MILLION_DOCKER_CACHE:-$PWD/.docker-cache}
export MILLION_DOCKER_CACHE=$CACHE
project=million-test-$$
KILL_AT=${KILL_AT:-60000}        # agent steps: kill one env server
RESTART_AT=${RESTART_AT:-150000} # agent steps: restart the agent container
TRAIN_TIMEOUT=${TRAIN_TIMEOUT:-1500}
run=quickstart

log() { echo "[test-docker +${SECONDS}s] $*"; }
fail() {
    echo "[test-docker +${SECONDS}s] FAILED: $*" >&2
    exit 1
}
trap 'fail "line $LINENO: $BASH_COMMAND exited with $?"' ERR

if docker compose version >/dev/null 2>&1; then
    COMPOSE=(docker compose)
elif command -v docker-compose >/dev/null; then
    COMPOSE=(docker-compose)
else
    fail "neither 'docker compose' nor 'docker-compose' is installed"
fi
export ENV_SERVER_IMAGE=million-env-server:test AGENT_IMAGE=million-agent:test \
    ENV_SERVERS=2 CONFIG=configs/$run.toml RUN=$run
compose() { "${COMPOSE[@]}" -p "$project" -f docker/compose.yaml "$@"; }

[[ -x $binary ]] || fail "$binary is missing: run 'make build' first"

# --- 1 + 2: images -----------------------------------------------------------------
t0=$SECONDS
docker/make-base-images.sh
# Wheels are fetched again only when the lock changed.
stamp=docker/offline/env-server/.lock-sha256
want=$(sha256sum requirements/env-server.lock | cut -d' ' -f1)
if [[ ! -f $stamp || $(cat "$stamp") != "$want" ]]; then
    rm -rf docker/offline/env-server
    docker/offline.sh env-server
    echo "$want" >"$stamp"
fi
t1=$SECONDS
docker build -q -f docker/env-server.Dockerfile \
    --build-arg PYTHON_IMAGE=million-base/python:3.11-slim -t "$ENV_SERVER_IMAGE" . >/dev/null
t2=$SECONDS
bundle=$CACHE/agent-bundle
docker/agent-bundle.sh "$binary" "$bundle"
cp docker/agent-train.sh "$bundle/bin/million-train"
docker build -q -f docker/agent-runtime.Dockerfile \
    --build-arg RUNTIME_IMAGE=million-base/debian:bookworm-slim -t "$AGENT_IMAGE" "$bundle" >/dev/null
t3=$SECONDS
size() { docker image inspect -f '{{.Size}}' "$1" | numfmt --to=iec; }
log "images: base + wheels $((t1 - t0)) s, env server $((t2 - t1)) s ($(size "$ENV_SERVER_IMAGE")), agent $((t3 - t2)) s ($(size "$AGENT_IMAGE"))"

# --- 3: the run --------------------------------------------------------------------
cleanup() {
    local rc=$?
    if ((rc != 0)) && [[ -n ${agent:-} ]]; then
        echo "--- agent log (last 60 lines) ---" >&2
        docker logs --tail 60 "$agent" >&2 || true
    fi
    compose down -v --remove-orphans >/dev/null 2>&1 || true
}
trap cleanup EXIT
compose up -d --no-build
agent=$(compose ps -q agent)
mapfile -t servers < <(compose ps -q env-server)
((${#servers[@]} == 2)) || fail "expected 2 env-server containers, got ${#servers[@]}"
log "up: 2 env servers healthy, agent ${agent:0:12} training $CONFIG"

steps() {
    docker exec "$agent" sh -c "tail -n 1 /runs/$run/metrics.jsonl 2>/dev/null" 2>/dev/null |
        grep -o '"step":[0-9]*' | cut -d: -f2 || true
}
running() { [[ $(docker inspect -f '{{.State.Running}}' "$agent") == true ]]; }
# Waits until the agent has logged at least $1 steps; false if training ended first.
wait_steps() {
    local s
    while running; do
        s=$(steps)
        [[ -n $s ]] && ((s >= $1)) && return 0
        ((SECONDS - t3 < TRAIN_TIMEOUT)) || fail "no $1 agent steps after $TRAIN_TIMEOUT s"
        sleep 2
    done
    return 1
}

wait_steps "$KILL_AT" || fail "training ended before $KILL_AT steps: nothing was killed"
victim=${servers[0]}
victim_ip=$(docker inspect -f '{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}' "$victim")
docker kill "$victim" >/dev/null
killed_at=$(steps)
log "killed env server ${victim:0:12} ($victim_ip) at $killed_at agent steps"

restarted_at=
if wait_steps "$RESTART_AT"; then
    restarted_at=$(steps)
    # SIGINT (the image's stop signal): final checkpoint, then the entry point resumes.
    docker restart -t 300 "$agent" >/dev/null
    log "restarted the agent container at $restarted_at agent steps"
fi

while running; do
    ((SECONDS - t3 < TRAIN_TIMEOUT)) || fail "training did not end within $TRAIN_TIMEOUT s"
    sleep 5
done
t4=$SECONDS
code=$(docker inspect -f '{{.State.ExitCode}}' "$agent")
out=$(docker logs "$agent" 2>&1 | sed "s/\x1b\[[0-9;]*m//g")

# --- 4: checks ---------------------------------------------------------------------
((code == 0)) || fail "the agent exited with $code"
pool_line=$(grep -m1 'env pool ready' <<<"$out") || fail "no 'env pool ready' in the agent's log"
for s in "${servers[@]}"; do
    ip=$(docker inspect -f '{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}' "$s")
    [[ $s == "$victim" ]] && ip=$victim_ip
    grep -q "$ip:50051" <<<"$pool_line" || fail "replica $ip got no envs: $pool_line"
done
grep -q 'env server lost; rebuilding' <<<"$out" || fail "the agent never noticed the kill"
grep -q 'envs rebuilt' <<<"$out" || fail "the lost envs were not rebuilt"
moved=$(grep -c 'envs moved to another replica' <<<"$out" || true)
if [[ -n $restarted_at ]]; then
    grep -q 'has checkpoints; resuming' <<<"$out" || fail "the restarted agent did not resume"
    grep -q '"resumed"\|resumed' <<<"$out" || fail "no 'resumed' in the agent's log"
fi
grep -q 'reason="target success reached"\|reason=target success reached' <<<"$out" ||
    fail "training stopped without reaching the target success: $(grep 'training stops' <<<"$out")"
train_eval=$(grep -oE 'eval train: success [0-9.]+' <<<"$out" | tail -1)
[[ -n $train_eval ]] || fail "no final evaluation in the agent's log"
victim_state=$(docker inspect -f '{{.State.Status}}, restarts {{.RestartCount}}' "$victim" 2>/dev/null || echo gone)
log "agent: exit 0, $(grep -oE '^[0-9]+ agent steps in [0-9]+ s' <<<"$out" | tail -1); final $train_eval; $(grep -oE 'eval test: success [0-9.]+' <<<"$out" | tail -1)"
log "kill at $killed_at steps: envs rebuilt ($moved shard(s) moved to the other replica); killed container now: $victim_state"
[[ -n $restarted_at ]] && log "agent restarted at $restarted_at steps and resumed from its checkpoint"
log "PASSED: images $((t3 - t0)) s, training $((t4 - t3)) s, total ${SECONDS} s"
