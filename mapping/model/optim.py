"""AdamW for a bank of instance networks stored as one (N, D) parameter, with one step count per row.

Kept apart from the field: the optimiser knows rows and moments, not networks. Growth of the bank
(a new instance mid-run) appends zero state for the new rows and leaves the others bit-exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor
from torch.optim.adam import adam as _functional_adam

from mapping.model.field import InstanceFieldBank


@dataclass(frozen=True)
class AdamConfig:
    """Adam with decoupled weight decay (AdamW), vMAP's settings by default."""

    lr: float = 1e-3
    """Learning rate (vMAP: 1e-3)."""
    betas: tuple[float, float] = (0.9, 0.999)
    """Moment decay rates."""
    eps: float = 1e-8
    """Denominator guard."""
    weight_decay: float = 0.013
    """Decoupled weight decay (vMAP's AdamW: 0.013)."""


class StackedAdam:
    """AdamW on a bank's (N, D) parameter with one step count per row.

    A row added to the bank starts with zero moments and step 0 (its own bias correction), while the
    other rows keep their state bit-exactly: growth never rebuilds the optimiser. ``step(rows)``
    updates only the given rows (an instance with no rays this step keeps its state unchanged).
    On CPU and CUDA the update is PyTorch's fused AdamW kernel (one pass over memory) on runs of rows
    that share a step count; elsewhere a reference implementation with the same arithmetic.
    """

    def __init__(self, bank: InstanceFieldBank, config: AdamConfig = AdamConfig()):
        self.bank = bank
        self.config = config
        self.exp_avg = torch.zeros_like(bank.params.detach())
        self.exp_avg_sq = torch.zeros_like(bank.params.detach())
        self.steps = torch.zeros(bank.num_instances, device=bank.device)  # float32, as the fused kernel wants

    def _sync(self) -> None:
        """Grow the state to the bank's rows (zero moments and steps for new rows)."""
        n, k = self.bank.num_instances, self.exp_avg.shape[0]
        if n < k:
            raise RuntimeError(f"bank shrank from {k} to {n} rows; the optimiser cannot follow")
        if n > k or self.exp_avg.device != self.bank.device:
            pad = torch.zeros(n - k, self.bank.param_dim, device=self.bank.device)
            self.exp_avg = torch.cat([self.exp_avg.to(self.bank.device), pad])
            self.exp_avg_sq = torch.cat([self.exp_avg_sq.to(self.bank.device), pad])
            self.steps = torch.cat([self.steps.to(self.bank.device), pad[:, 0]])

    def zero_grad(self) -> None:
        self.bank.params.grad = None

    @torch.no_grad()
    def reset_rows(self, rows: Sequence[int]) -> None:
        """Forget the moments and step counts of ``rows`` (e.g. after replacing their parameters)."""
        self._sync()
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.bank.device)
        self.exp_avg[rows] = 0.0
        self.exp_avg_sq[rows] = 0.0
        self.steps[rows] = 0.0

    @torch.no_grad()
    def step(self, rows: Sequence[int] | Tensor | None = None) -> None:
        """One AdamW step on all rows with a gradient, or only on ``rows``."""
        self._sync()
        param, grad = self.bank.params, self.bank.params.grad
        if grad is None:
            return
        n = param.shape[0]
        idx = list(range(n)) if rows is None else sorted(set(torch.as_tensor(rows).reshape(-1).tolist()))
        if not idx:
            return
        # Runs of consecutive rows with equal step counts share one step tensor and one flat view: in
        # the usual case (all rows stepped together) the whole bank is a single fused update (4x faster
        # at 100 rows than one tensor per row).
        step_of = self.steps.tolist()
        runs: list[list[int]] = []
        for i in idx:
            if runs and i == runs[-1][1] and step_of[i] == step_of[runs[-1][0]]:
                runs[-1][1] = i + 1
            else:
                runs.append([i, i + 1])
        flat = [[t[a:b].reshape(-1) for a, b in runs] for t in (param.detach(), grad, self.exp_avg, self.exp_avg_sq)]
        run_steps = [self.steps[a].clone() for a, _ in runs]
        cfg = self.config
        if param.device.type in ("cpu", "cuda") and param.dtype == torch.float32:
            _functional_adam(*flat, [], run_steps, fused=True, decoupled_weight_decay=True, amsgrad=False,
                             beta1=cfg.betas[0], beta2=cfg.betas[1], lr=cfg.lr,
                             weight_decay=cfg.weight_decay, eps=cfg.eps, maximize=False)
        else:
            reference_adamw(*flat, run_steps, cfg)
        for (a, b), step in zip(runs, run_steps):
            self.steps[a:b] = step

    def state_dict(self) -> dict:
        self._sync()
        return {"exp_avg": self.exp_avg.clone(), "exp_avg_sq": self.exp_avg_sq.clone(), "steps": self.steps.clone(),
                "config": {"lr": self.config.lr, "betas": tuple(self.config.betas), "eps": self.config.eps,
                           "weight_decay": self.config.weight_decay}}

    def load_state_dict(self, state: dict) -> None:
        dev = self.bank.device
        self.exp_avg = state["exp_avg"].to(dev).clone()
        self.exp_avg_sq = state["exp_avg_sq"].to(dev).clone()
        self.steps = state["steps"].to(dev).clone()
        self.config = AdamConfig(**{**state["config"], "betas": tuple(state["config"]["betas"])})
        self._sync()


def reference_adamw(params: list[Tensor], grads: list[Tensor], exp_avgs: list[Tensor],
                     exp_avg_sqs: list[Tensor], steps: list[Tensor], cfg: AdamConfig) -> None:
    """Per-row AdamW with PyTorch's arithmetic (used where the fused kernel is unavailable, and in tests)."""
    beta1, beta2 = cfg.betas
    for p, g, m, v, s in zip(params, grads, exp_avgs, exp_avg_sqs, steps):
        s += 1
        t = float(s)
        p.mul_(1.0 - cfg.lr * cfg.weight_decay)
        m.lerp_(g, 1.0 - beta1)
        v.mul_(beta2).addcmul_(g, g, value=1.0 - beta2)
        bias1, bias2 = 1.0 - beta1**t, 1.0 - beta2**t
        denom = (v.sqrt() / math.sqrt(bias2)).add_(cfg.eps)
        p.addcdiv_(m, denom, value=-cfg.lr / bias1)
