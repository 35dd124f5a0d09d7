"""PyTorch reference of the Rust learner (agent/src/learner.rs): the same network and V-MPO update.

`million bench learner --reference` writes the Rust learner's weights, one batch and the
agent config to a directory, then runs this script on them:

    learner_reference.py check DIR              loss terms before and after one update (JSON)
    learner_reference.py time DIR --threads N --iters K      updates/s at N intra-op threads
    learner_reference.py serve DIR              JSON commands on stdin, one JSON answer a line

DIR holds `config.json` (the agent config as serde writes it), `weights.safetensors` (every
variable of the learner's VarStore, under its tch name) and `batch.safetensors` (the
SegmentBatch fields). Everything the Rust config can select is mirrored: Pop-Art on/off and
debiased, n-step or λ-returns, clamp- or log-form multipliers with their own step size, KL
from the behaviour policy or from a target network. The computation follows the Rust code
operation by operation (same fused gate matrices, same relative-bias lookup, same masks), so
the loss terms agree to float rounding; the update is idiomatic PyTorch (modules, autograd,
torch.optim.Adam with the fused CPU kernel).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

Config = dict[str, Any]

# ---------------------------------------------------------------------------------------------
# safetensors (the format is a little-endian u64 header length, a JSON header, raw data)
# ---------------------------------------------------------------------------------------------

_DTYPES = {
    "F32": torch.float32,
    "F64": torch.float64,
    "I64": torch.int64,
    "I32": torch.int32,
    "BOOL": torch.bool,
    "U8": torch.uint8,
}


def read_safetensors(path: Path) -> dict[str, Tensor]:
    """All tensors of a safetensors file, as CPU tensors."""
    data = path.read_bytes()
    header_len = int.from_bytes(data[:8], "little")
    header = json.loads(data[8 : 8 + header_len])
    base = 8 + header_len
    out: dict[str, Tensor] = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        dtype = _DTYPES[info["dtype"]]
        start, end = info["data_offsets"]
        if end > start:
            flat = torch.frombuffer(bytearray(data[base + start : base + end]), dtype=dtype)
        else:
            flat = torch.empty(0, dtype=dtype)
        out[name] = flat.reshape(info["shape"])
    return out


# ---------------------------------------------------------------------------------------------
# The network (agent/src/model/{mod,gtrxl,policy,popart}.rs)
# ---------------------------------------------------------------------------------------------


class Gate(nn.Module):
    """GRU-type gate: r, z, h from W y (one matrix for W_r, W_z, W_g) and U x."""

    def __init__(self, d: int, bias_init: float) -> None:
        super().__init__()
        self.w = nn.Linear(d, 3 * d, bias=False)
        self.u_rz = nn.Linear(d, 2 * d, bias=False)
        self.u_g = nn.Linear(d, d, bias=False)
        self.b_g = nn.Parameter(torch.full((d,), bias_init))

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        wr, wz, wg = self.w(y).chunk(3, -1)
        ur, uz = self.u_rz(x).chunk(2, -1)
        r = torch.sigmoid(wr + ur)
        z = torch.sigmoid(wz + uz - self.b_g)
        h = torch.tanh(wg + self.u_g(r * x))
        return x + z * (h - x)


class GtrxlLayer(nn.Module):
    def __init__(self, d: int, heads: int, ff: int, gate_bias: float, max_distance: int) -> None:
        super().__init__()
        self.heads = heads
        self.d = d
        self.ln_attn = nn.LayerNorm(d)
        self.q = nn.Linear(d, d)
        self.kv = nn.Linear(d, 2 * d)
        self.out = nn.Linear(d, d)
        self.gate_attn = Gate(d, gate_bias)
        self.ln_ff = nn.LayerNorm(d)
        self.ff1 = nn.Linear(d, ff)
        self.ff2 = nn.Linear(ff, d)
        self.gate_ff = Gate(d, gate_bias)
        # Learned bias per head and relative distance (query index - key index).
        self.rel_bias = nn.Parameter(torch.zeros(heads, max_distance))

    def forward(self, x: Tensor, memory: Tensor, mask: Tensor, distance: Tensor) -> Tensor:
        """`x` [B, T, d], `memory` [B, m, d], `mask` [B, 1, T, K], `distance` [T, K] (clamped)."""
        b, t, _ = x.shape
        dh = self.d // self.heads
        x_norm = self.ln_attn(x)
        rows = torch.cat([memory, x_norm], 1)
        n = rows.shape[1]
        k, v = self.kv(rows).chunk(2, -1)
        k = k.view(b, n, self.heads, dh).transpose(1, 2)
        v = v.view(b, n, self.heads, dh).transpose(1, 2)
        q = self.q(x_norm).view(b, t, self.heads, dh).transpose(1, 2)
        rel = self.rel_bias.index_select(1, distance.flatten()).view(self.heads, t, n)
        bias = mask + rel.unsqueeze(0)
        scores = (q * (1.0 / math.sqrt(dh))) @ k.transpose(-2, -1) + bias
        y = (scores.softmax(-1) @ v).transpose(1, 2).reshape(b, t, self.d)
        x = self.gate_attn(x, F.relu(self.out(y)))
        f = F.relu(self.ff2(F.relu(self.ff1(self.ln_ff(x)))))
        return self.gate_ff(x, f)


class PopArt(nn.Module):
    """One normalised output row per task, with running mu_k, nu_k, sigma_k kept in f64."""

    def __init__(self, hidden: int, num_tasks: int, cfg: Config) -> None:
        super().__init__()
        self.cfg = cfg
        self.weight = nn.Parameter(torch.zeros(num_tasks, hidden))
        self.bias = nn.Parameter(torch.zeros(num_tasks))
        for name, v in (("mu", 0.0), ("nu", 1.0), ("sigma", 1.0), ("updates", 0.0)):
            self.register_buffer(name, torch.full((num_tasks,), v, dtype=torch.float64))

    def normalised(self, features: Tensor, task: Tensor) -> Tensor:
        w = self.weight.index_select(0, task)
        return (features * w).sum(-1) + self.bias.index_select(0, task)

    def unnormalise(self, normalised: Tensor, task: Tensor) -> Tensor:
        dtype = normalised.dtype
        sigma = self.sigma.index_select(0, task).to(dtype)
        return normalised * sigma + self.mu.index_select(0, task).to(dtype)

    def normalise_targets(self, targets: Tensor, task: Tensor) -> Tensor:
        dtype = targets.dtype
        mu = self.mu.index_select(0, task).to(dtype)
        return (targets - mu) / self.sigma.index_select(0, task).to(dtype)

    def state(self) -> list[Tensor]:
        return [self.weight, self.bias, self.mu, self.nu, self.sigma, self.updates]

    def snapshot(self) -> list[Tensor]:
        return [t.detach().clone() for t in self.state()]

    @torch.no_grad()
    def restore(self, snapshot: list[Tensor]) -> None:
        for dst, src in zip(self.state(), snapshot, strict=True):
            dst.copy_(src)

    @torch.no_grad()
    def update(self, targets: Tensor, task: Tensor, valid: Tensor) -> float:
        """Moves the statistics of the tasks present towards their targets, preserving outputs;
        returns the mean sigma of those tasks."""
        cfg = self.cfg
        if not cfg["enabled"]:
            return 1.0
        k = self.mu.shape[0]
        g = targets.detach().double()
        w = valid.double()
        zeros = torch.zeros(k, dtype=torch.float64, device=g.device)
        count = zeros.index_add(0, task, w)
        total = zeros.index_add(0, task, g * w)
        total_sq = zeros.index_add(0, task, g.square() * w)
        present = count > 0
        n = count.clamp_min(1.0)
        updates = self.updates + present.double()
        if cfg["debias"]:
            beta = updates.clamp_min(1.0).reciprocal().clamp_min(cfg["beta"])
        else:
            beta = torch.full_like(zeros, cfg["beta"])
        keep = 1.0 - beta
        mu_new = torch.where(present, self.mu * keep + total / n * beta, self.mu)
        nu_new = torch.where(present, self.nu * keep + total_sq / n * beta, self.nu)
        sigma_new = torch.where(
            present,
            (nu_new - mu_new.square())
            .clamp_min(0.0)
            .sqrt()
            .clamp(cfg["sigma_min"], cfg["sigma_max"]),
            self.sigma,
        )
        dtype = self.weight.dtype
        scale = (self.sigma / sigma_new).to(dtype)
        new_bias = ((self.sigma * self.bias.double() + self.mu - mu_new) / sigma_new).to(dtype)
        self.weight.mul_(scale.unsqueeze(1))
        self.bias.copy_(new_bias)
        self.mu.copy_(mu_new)
        self.nu.copy_(nu_new)
        self.sigma.copy_(sigma_new)
        self.updates.copy_(updates)
        shown = sigma_new[present] if bool(present.any()) else sigma_new
        return shown.mean().item()


@dataclass
class SegmentOutput:
    mean: Tensor
    std: Tensor
    value_features: Tensor


class ObsNorm(nn.Module):
    """Running per-feature normalisation of the chosen token fields (model/obs_norm.rs)."""

    CLIP = 10.0

    def __init__(self, mc: Config) -> None:
        super().__init__()
        chosen = set(mc["obs_norm"])
        applied = [f["key"] in chosen for f in mc["observation"] for _ in range(f["size"])]
        obs = len(applied)
        self.register_buffer("mean", torch.zeros(obs, dtype=torch.float64))
        self.register_buffer("var", torch.ones(obs, dtype=torch.float64))
        self.register_buffer("count", torch.zeros(1, dtype=torch.float64))
        self.register_buffer("applied", torch.tensor(applied))
        self.pending_n = 0
        self.register_buffer("pending_sum", torch.zeros(obs, dtype=torch.float64))
        self.register_buffer("pending_sq", torch.zeros(obs, dtype=torch.float64))

    def forward(self, obs: Tensor) -> Tensor:
        scale = (self.var + 1e-8).rsqrt().to(obs.dtype)
        normalised = ((obs - self.mean.to(obs.dtype)) * scale).clamp(-self.CLIP, self.CLIP)
        return torch.where(self.applied, normalised, obs)

    @torch.no_grad()
    def observe(self, obs: Tensor) -> None:
        """Adds the rows of `obs` to the pending moments (used from the next commit on)."""
        x = obs.reshape(-1, obs.shape[-1]).double()
        self.pending_n += x.shape[0]
        self.pending_sum += x.sum(0)
        self.pending_sq += x.square().sum(0)

    @torch.no_grad()
    def commit(self) -> None:
        n, seen = float(self.pending_n), self.count.item()
        if n == 0:
            return
        total = seen + n
        batch_mean = self.pending_sum / n
        batch_var = (self.pending_sq / n - batch_mean.square()).clamp_min(0.0)
        delta = batch_mean - self.mean
        m2 = self.var * seen + batch_var * n + delta.square() * (seen * n / total)
        self.mean += delta * (n / total)
        self.var.copy_(m2 / total)
        self.count.fill_(total)
        self.pending_n = 0
        self.pending_sum.zero_()
        self.pending_sq.zero_()


class Model(nn.Module):
    """Token → [ObsNorm] → LayerNorm → Linear → GTrXL → Gaussian policy and Pop-Art value."""

    def __init__(self, mc: Config, popart: Config) -> None:
        super().__init__()
        obs = sum(f["size"] for f in mc["observation"])
        d = mc["d_model"]
        self.memory_len = mc["memory_len"]
        self.action_dim = mc["action_dim"]
        self.min_std = mc["min_std"]
        max_distance = mc["memory_len"] + mc["segment_len"]
        self.obs_norm = ObsNorm(mc) if mc.get("obs_norm") else None
        self.input_norm = nn.LayerNorm(obs)
        self.input_proj = nn.Linear(obs, d)
        self.layers = nn.ModuleList(
            GtrxlLayer(d, mc["heads"], mc["ff_dim"], mc["gate_bias_init"], max_distance)
            for _ in range(mc["layers"])
        )
        self.policy_hidden = nn.Linear(d, mc["policy_hidden"])
        self.policy_out = nn.Linear(mc["policy_hidden"], 2 * mc["action_dim"])
        self.value_hidden = nn.Linear(d, mc["value_hidden"])
        self.popart = PopArt(mc["value_hidden"], mc["num_tasks"], popart)

    def tch_names(self, prefix: str = "") -> dict[str, Tensor]:
        """Every tensor under the name the Rust VarStore gives it."""

        def linear(name: str, m: nn.Linear) -> dict[str, Tensor]:
            out = {f"{name}.weight": m.weight}
            if m.bias is not None:
                out[f"{name}.bias"] = m.bias
            return out

        def norm(name: str, m: nn.LayerNorm) -> dict[str, Tensor]:
            return {f"{name}.weight": m.weight, f"{name}.bias": m.bias}

        def gate(name: str, g: Gate) -> dict[str, Tensor]:
            return {
                **linear(f"{name}.w", g.w),
                **linear(f"{name}.u_rz", g.u_rz),
                **linear(f"{name}.u_g", g.u_g),
                f"{name}.b_g": g.b_g,
            }

        names = {
            **norm("input_norm", self.input_norm),
            **linear("input_proj", self.input_proj),
            **linear("policy.hidden", self.policy_hidden),
            **linear("policy.out", self.policy_out),
            **linear("value_hidden", self.value_hidden),
            "popart.weight": self.popart.weight,
            "popart.bias": self.popart.bias,
            "popart.mu": self.popart.mu,
            "popart.nu": self.popart.nu,
            "popart.sigma": self.popart.sigma,
            "popart.updates": self.popart.updates,
        }
        if self.obs_norm is not None:
            on = self.obs_norm
            names |= {"obs_norm.mean": on.mean, "obs_norm.var": on.var, "obs_norm.count": on.count}
        for i, layer in enumerate(self.layers):
            assert isinstance(layer, GtrxlLayer)
            p = f"core.layer{i}"
            names |= {
                **norm(f"{p}.ln_attn", layer.ln_attn),
                **linear(f"{p}.q", layer.q),
                **linear(f"{p}.kv", layer.kv),
                **linear(f"{p}.out", layer.out),
                **gate(f"{p}.gate_attn", layer.gate_attn),
                **norm(f"{p}.ln_ff", layer.ln_ff),
                **linear(f"{p}.ff1", layer.ff1),
                **linear(f"{p}.ff2", layer.ff2),
                **gate(f"{p}.gate_ff", layer.gate_ff),
                f"{p}.rel_bias": layer.rel_bias,
            }
        return {prefix + k: v for k, v in names.items()}

    def forward(
        self, obs: Tensor, episode_start: Tensor, memory: Tensor, memory_len: Tensor
    ) -> SegmentOutput:
        m = self.memory_len
        t = obs.shape[1]
        device = obs.device
        # Key index of each step's episode start: keys before it belong to an earlier episode.
        steps = torch.arange(t, device=device) + m
        starts = torch.where(episode_start, steps, torch.zeros(1, dtype=torch.long, device=device))
        valid_from = torch.maximum(starts.cummax(1).values, m - memory_len.unsqueeze(1))
        keys = torch.arange(m + t, device=device)
        allowed = (keys >= valid_from.unsqueeze(-1)) & (keys <= steps.view(1, t, 1))
        mask = torch.zeros(allowed.shape, device=device).masked_fill(~allowed, float("-inf"))
        mask = mask.unsqueeze(1)  # [B, 1, T, K]
        max_distance = self.layers[0].rel_bias.shape[1]
        distance = (steps.unsqueeze(1) - keys.unsqueeze(0)).clamp(0, max_distance - 1)

        if self.obs_norm is not None:
            obs = self.obs_norm(obs)
        x = self.input_proj(self.input_norm(obs))
        for layer, mem in zip(self.layers, memory.unbind(0), strict=True):
            x = layer(x, mem, mask, distance)
        out = self.policy_out(F.relu(self.policy_hidden(x)))
        a = self.action_dim
        mean = torch.tanh(out[..., :a])
        std = F.softplus(out[..., a:]) + self.min_std
        return SegmentOutput(mean, std, F.relu(self.value_hidden(x)))


# ---------------------------------------------------------------------------------------------
# V-MPO (agent/src/algo/{returns,vmpo}.rs, agent/src/learner.rs)
# ---------------------------------------------------------------------------------------------


def bootstrapped_returns(
    rewards: Tensor,
    values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    gamma: float,
    lam: float,
) -> tuple[Tensor, Tensor]:
    """n-step (λ = 1) or λ-returns over a segment and the mask of trainable steps. `values`
    has T columns (the last step only bootstraps) or T + 1 (V(s_T) after the segment)."""
    t_len = rewards.shape[1]
    values = values.detach()
    cut = truncated & ~terminated
    continues = (~terminated).to(rewards.dtype)
    learned = t_len if values.shape[1] > t_len else t_len - 1
    nxt = values[:, -1]
    columns = [] if learned == t_len else [nxt]
    for t in range(learned - 1, -1, -1):
        ahead = values[:, t + 1] * (1.0 - lam) + nxt * lam if lam < 1.0 else nxt
        through = rewards[:, t] + continues[:, t] * ahead * gamma
        nxt = torch.where(cut[:, t], values[:, t], through)
        columns.append(nxt)
    columns.reverse()
    trainable = ~cut
    trainable[:, learned:] = False
    return torch.stack(columns, 1), trainable


def gaussian_log_prob(mean: Tensor, std: Tensor, action: Tensor) -> Tensor:
    z = (action - mean) / std
    return (z.square() * -0.5 - std.log() - 0.5 * math.log(2.0 * math.pi)).sum(-1)


def multiplier_loss(alpha: Tensor, kl: Tensor, eps: float, w: Tensor, count: Tensor) -> Tensor:
    per_step = alpha * (eps - kl.detach()) + alpha.detach() * kl
    return (per_step * w).sum() / count


class Multipliers(nn.Module):
    """eta, alpha_mu, alpha_sigma: the multipliers (clamp form) or their logarithms (log form)."""

    def __init__(self, form: str) -> None:
        super().__init__()
        self.log_form = form == "log"
        self.eta = nn.Parameter(torch.ones(()))
        self.alpha_mu = nn.Parameter(torch.ones(()))
        self.alpha_sigma = nn.Parameter(torch.ones(()))

    def value(self, raw: Tensor) -> Tensor:
        return raw.exp() if self.log_form else raw

    @torch.no_grad()
    def project(self, floor: float, ceiling: float) -> None:
        low, high = (math.log(floor), math.log(ceiling)) if self.log_form else (floor, ceiling)
        for p in self.parameters():
            p.clamp_(low, high)


@dataclass
class Batch:
    obs: Tensor
    actions: Tensor
    rewards: Tensor
    terminated: Tensor
    truncated: Tensor
    episode_start: Tensor
    instruction: Tensor
    task: Tensor
    behaviour_mean: Tensor
    behaviour_std: Tensor
    bootstrap_obs: Tensor
    bootstrap_start: Tensor
    memory: Tensor
    memory_len: Tensor

    @classmethod
    def load(cls, path: Path, device: torch.device) -> Batch:
        t = read_safetensors(path)
        return cls(**{k: t[k].to(device) for k in cls.__dataclass_fields__})


TERMS = (
    "loss",
    "policy_loss",
    "temperature_loss",
    "alpha_mu_loss",
    "alpha_sigma_loss",
    "value_loss",
)


class Learner:
    def __init__(self, cfg: Config, weights: dict[str, Tensor], device: torch.device) -> None:
        self.cfg = cfg
        mc, v = cfg["model"], cfg["vmpo"]
        if v.get("per_task_e_step", False):
            # A config this reference does not model is refused, as a mismatch of weights is.
            raise ValueError(
                "the reference implements the paper's batch-wide E-step only "
                "(vmpo.per_task_e_step = false)"
            )
        self.model = Model(mc, cfg["popart"]).to(device)
        self.multipliers = Multipliers(v["multiplier_form"]).to(device)
        self.target: Model | None = None
        names = self.model.tch_names() | {
            "vmpo.eta": self.multipliers.eta,
            "vmpo.alpha_mu": self.multipliers.alpha_mu,
            "vmpo.alpha_sigma": self.multipliers.alpha_sigma,
        }
        if v["kl_reference"] == "target":
            self.target = Model(mc, cfg["popart"]).to(device).requires_grad_(False)
            names |= self.target.tch_names("target.")
        missing = sorted(set(names) - set(weights))
        unexpected = sorted(set(weights) - set(names))
        if missing or unexpected:
            raise ValueError(f"weights do not match: missing {missing}, unexpected {unexpected}")
        with torch.no_grad():
            for name, t in names.items():
                if t.shape != weights[name].shape:
                    raise ValueError(f"{name}: {tuple(weights[name].shape)} != {tuple(t.shape)}")
                t.copy_(weights[name])
        opt = cfg["optim"]
        multiplier_lr = v["multiplier_lr"] or opt["lr"]
        self.adam = torch.optim.Adam(
            [
                {"params": list(self.model.parameters())},
                {"params": list(self.multipliers.parameters()), "lr": multiplier_lr},
            ],
            lr=opt["lr"],
            betas=(opt["beta1"], opt["beta2"]),
            eps=opt["eps"],
            fused=True,
        )
        self.params = [p for g in self.adam.param_groups for p in g["params"]]
        self.updates = 0

    def sync_target(self) -> None:
        if self.target is None:
            return
        with torch.no_grad():
            src = self.model.tch_names()
            for name, t in self.target.tch_names("target.").items():
                t.copy_(src[name.removeprefix("target.")])

    def losses(self, b: Batch) -> dict[str, Any]:
        """Steps 1-6 of the Rust update: forward, returns, Pop-Art update, the loss terms."""
        v = self.cfg["vmpo"]
        n_seg, t_len, _ = b.obs.shape
        n = n_seg * t_len
        a = self.cfg["model"]["action_dim"]
        popart = self.model.popart

        # 1. Forward every step from the memory stored at its segment's start; with
        #    learn_last_step the state after the segment runs as step T, for its value alone.
        if v["learn_last_step"]:
            out = self.model(
                torch.cat([b.obs, b.bootstrap_obs.unsqueeze(1)], 1),
                torch.cat([b.episode_start, b.bootstrap_start.unsqueeze(1)], 1),
                b.memory,
                b.memory_len,
            )
            after_features = out.value_features[:, t_len]
            out = SegmentOutput(
                out.mean[:, :t_len], out.std[:, :t_len], out.value_features[:, :t_len]
            )
        else:
            out = self.model(b.obs, b.episode_start, b.memory, b.memory_len)
        features = out.value_features.reshape(n, -1)
        task = b.task.reshape(n)
        num_tasks = self.cfg["model"]["num_tasks"]

        # 2. Targets bootstrapped from the current (unnormalised) value.
        with torch.no_grad():
            values = popart.unnormalise(popart.normalised(features, task), task).view(n_seg, t_len)
            if v["learn_last_step"]:
                last_task = b.task[:, t_len - 1]
                after = popart.unnormalise(popart.normalised(after_features, last_task), last_task)
                values = torch.cat([values, after.unsqueeze(1)], 1)
        returns, trainable = bootstrapped_returns(
            b.rewards,
            values,
            b.terminated,
            b.truncated,
            v["gamma"],
            v["lambda"],
        )
        g = returns.reshape(n)
        value_mask = trainable.reshape(n)
        policy_mask = value_mask & ~b.instruction.reshape(n)

        # 3. Pop-Art update, normalised targets and clipped advantages.
        popart_before = popart.snapshot()
        mean_sigma = popart.update(g, task, value_mask)
        target = popart.normalise_targets(g, task)
        predicted = popart.normalised(features, task)
        clip = v["advantage_clip"]
        advantages = (target - predicted.detach()).clamp(-clip, clip)

        # 4. Value loss.
        value_w = value_mask.float()
        value_count = value_w.sum().clamp_min(1.0)
        value_loss = ((predicted - target).square() * value_w).sum() / value_count * 0.5

        # 5. Policy and temperature over the top half of the policy steps.
        mean = out.mean.reshape(n, a)
        std = out.std.reshape(n, a)
        mult = self.multipliers
        eta = mult.value(mult.eta)
        valid = int(policy_mask.sum().item())
        k = math.floor(valid * v["top_fraction"])
        if k > 0:
            scores = advantages.detach().masked_fill(~policy_mask, float("-inf"))
            idx = scores.topk(k, 0, True, False).indices
            top = advantages.index_select(0, idx).detach()
            psi = (top / eta.detach()).softmax(0)
            log_prob = gaussian_log_prob(
                mean.index_select(0, idx),
                std.index_select(0, idx),
                b.actions.reshape(n, a).index_select(0, idx),
            )
            policy_loss = -(psi * log_prob).sum()
            temperature_loss = eta * v["eps_eta"] + eta * ((top / eta).logsumexp(0) - math.log(k))
            psi_mass = torch.zeros(num_tasks, device=b.obs.device).scatter_add(
                0, task.index_select(0, idx), psi.float()
            )
        else:
            policy_loss = torch.zeros((), device=b.obs.device)
            temperature_loss = torch.zeros((), device=b.obs.device)
            psi_mass = torch.zeros(num_tasks, device=b.obs.device)
        task_policy_steps = torch.zeros(num_tasks, device=b.obs.device).scatter_add(
            0, task, policy_mask.float()
        )

        # 6. Decoupled KL from the behaviour policy or the target network.
        if self.target is not None:
            with torch.no_grad():
                o = self.target(b.obs, b.episode_start, b.memory, b.memory_len)
            old_mean, old_std = o.mean.reshape(n, a), o.std.reshape(n, a)
        else:
            old_mean = b.behaviour_mean.reshape(n, a)
            old_std = b.behaviour_std.reshape(n, a)
        kl_mu = ((mean - old_mean).square() / old_std.square()).sum(-1) * 0.5
        ratio = old_std.square() / std.square()
        kl_sigma = (ratio - 1.0 - ratio.log()).sum(-1) * 0.5
        pw = policy_mask.float()
        policy_count = pw.sum().clamp_min(1.0)
        alpha_mu_loss = multiplier_loss(
            mult.value(mult.alpha_mu), kl_mu, v["eps_alpha_mu"], pw, policy_count
        )
        alpha_sigma_loss = multiplier_loss(
            mult.value(mult.alpha_sigma), kl_sigma, v["eps_alpha_sigma"], pw, policy_count
        )
        loss = policy_loss + temperature_loss + alpha_mu_loss + alpha_sigma_loss + value_loss
        return {
            "loss": loss,
            "policy_loss": policy_loss,
            "temperature_loss": temperature_loss,
            "alpha_mu_loss": alpha_mu_loss,
            "alpha_sigma_loss": alpha_sigma_loss,
            "value_loss": value_loss,
            "kl_mu": kl_mu,
            "kl_sigma": kl_sigma,
            "g": g,
            "advantages": advantages,
            "std": std,
            "pw": pw,
            "value_w": value_w,
            "selected": k,
            "task": task,
            "psi_mass": psi_mass,
            "task_policy_steps": task_policy_steps,
            "mean_sigma": mean_sigma,
            "popart_before": popart_before,
        }

    def metrics(self, t: dict[str, Any], loss_value: float) -> dict[str, Any]:
        """The scalars of `UpdateMetrics`, with the multipliers as they are now."""
        pw, value_w = t["pw"], t["value_w"]
        policy_steps = pw.sum().item()
        value_steps = value_w.sum().item()

        def masked_mean(x: Tensor, w: Tensor, count: float) -> float:
            return (x.detach() * w).sum().item() / max(count, 1.0)

        steps = t["task_policy_steps"]

        def task_mean(x: Tensor) -> Tensor:
            """A per-step value's mean over each task's policy steps, [num_tasks]."""
            sums = torch.zeros_like(steps).scatter_add(0, t["task"], x.detach().float() * pw)
            return sums / steps.clamp_min(1.0)

        def per_task(values: Tensor) -> dict[str, float]:
            """Task id -> value, for the tasks with policy steps in the batch."""
            return {
                str(i): v
                for i, (v, n) in enumerate(zip(values.tolist(), steps.tolist(), strict=True))
                if n > 0
            }

        mult = self.multipliers
        out = {name: t[name].item() for name in TERMS}
        out |= {
            "loss": loss_value,
            "eta": mult.value(mult.eta).item(),
            "alpha_mu": mult.value(mult.alpha_mu).item(),
            "alpha_sigma": mult.value(mult.alpha_sigma).item(),
            "kl_mu": masked_mean(t["kl_mu"], pw, policy_steps),
            "kl_sigma": masked_mean(t["kl_sigma"], pw, policy_steps),
            "mean_return": masked_mean(t["g"], value_w, value_steps),
            "mean_advantage": masked_mean(t["advantages"], pw, policy_steps),
            "policy_steps": policy_steps,
            "selected_steps": t["selected"],
            "value_steps": value_steps,
            "popart_mean_sigma": t["mean_sigma"],
            "mean_std": masked_mean(t["std"].mean(-1), pw, policy_steps),
            # Task id -> sum of psi over its kept steps, for tasks with policy steps.
            "task_psi_mass": per_task(t["psi_mass"]),
            "task_mean_std": per_task(task_mean(t["std"].mean(-1))),
            "task_kl_mu": per_task(task_mean(t["kl_mu"])),
        }
        return out

    def loss_terms(self, b: Batch) -> dict[str, float]:
        """What an update would minimise, changing nothing (Pop-Art statistics put back)."""
        with torch.no_grad():
            t = self.losses(b)
        self.model.popart.restore(t["popart_before"])
        return self.metrics(t, t["loss"].item())

    def update(self, b: Batch) -> dict[str, float]:
        """One V-MPO update; nothing changes when the loss or a gradient is not finite."""
        t = self.losses(b)
        loss = t["loss"]
        loss_value = loss.item()
        if not math.isfinite(loss_value):
            self.model.popart.restore(t["popart_before"])
            raise FloatingPointError(f"non-finite loss ({loss_value})")
        self.adam.zero_grad()
        loss.backward()
        grads = [p.grad for p in self.params if p.grad is not None]
        if not bool(torch.stack([g.isfinite().all() for g in grads]).all()):
            self.adam.zero_grad()
            self.model.popart.restore(t["popart_before"])
            raise FloatingPointError(f"non-finite gradient (loss {loss_value})")
        self.adam.step()
        v = self.cfg["vmpo"]
        self.multipliers.project(v["min_multiplier"], v["max_multiplier"])
        sync = (self.updates + 1) % self.cfg["buffer"]["target_period"] == 0
        if self.model.obs_norm is not None:
            self.model.obs_norm.observe(b.obs)
            if sync:
                self.model.obs_norm.commit()
        self.updates += 1
        if sync:
            self.sync_target()
        return self.metrics(t, loss_value)


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------


def load(directory: Path, device: torch.device) -> tuple[Learner, Batch]:
    cfg = json.loads((directory / "config.json").read_text())
    weights = read_safetensors(directory / "weights.safetensors")
    return Learner(cfg, weights, device), Batch.load(directory / "batch.safetensors", device)


def check(learner: Learner, batch: Batch) -> dict[str, Any]:
    """Loss terms on the given weights, the metrics of one update, and the terms after it."""
    before = learner.loss_terms(batch)
    update = learner.update(batch)
    return {"before": before, "update": update, "after": learner.loss_terms(batch)}


def time_updates(learner: Learner, batch: Batch, threads: int, iters: int) -> dict[str, Any]:
    """`iters` timed updates at `threads` intra-op threads, after one untimed update."""
    torch.set_num_threads(threads)
    learner.update(batch)
    sync = torch.cuda.synchronize if batch.obs.is_cuda else (lambda: None)
    sync()
    start = time.perf_counter()
    for _ in range(iters):
        learner.update(batch)
    sync()
    seconds = time.perf_counter() - start
    return {
        "threads": threads,
        "iters": iters,
        "seconds": seconds,
        "updates_per_s": iters / seconds,
    }


def serve(learner: Learner, batch: Batch) -> None:
    """Answers `{"op": "check"}` and `{"op": "time", "threads": N, "iters": K}` lines."""
    print(json.dumps({"ready": True, "torch": torch.__version__}), flush=True)
    for line in sys.stdin:
        if not line.strip():
            continue
        cmd = json.loads(line)
        if cmd["op"] == "check":
            answer = check(learner, batch)
        elif cmd["op"] == "time":
            answer = time_updates(learner, batch, cmd["threads"], cmd["iters"])
        elif cmd["op"] == "quit":
            return
        else:
            answer = {"error": f"unknown op {cmd['op']!r}"}
        print(json.dumps(answer), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("mode", choices=["check", "time", "serve"])
    parser.add_argument("dir", type=Path, help="weights, batch and config written by Rust")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="intra-op threads")
    parser.add_argument("--iters", type=int, default=5, help="timed updates (time mode)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    learner, batch = load(args.dir, torch.device(args.device))
    if args.mode == "check":
        print(json.dumps(check(learner, batch)))
    elif args.mode == "time":
        print(json.dumps(time_updates(learner, batch, args.threads, args.iters)))
    else:
        serve(learner, batch)


if __name__ == "__main__":
    main()
