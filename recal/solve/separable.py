"""A swarm over a separable quadratic: its blocks of directions searched side by side.

In the whitened phase (:func:`recal.solve.phases.whitened_phase`) one unit is one sigma along
each observable direction, and the swarm objective's Gauss-Newton model
(:class:`recal.solve.surrogate.SurrogateProblem`, every residual linear) is, per Monte Carlo run
r, ``c_r + g_r.x + x^T H x`` with H the identity over R - 1 up to finite-difference error. The
objective is therefore a sum over any partition of the directions, and minimising it is
minimising each part. The seed's phases search one category of 3 to 6 coefficients at a time
(seed 000 section 3.3.2); here the whitened directions are cut into blocks of at most
``phase.blocks`` and every block of every run is one swarm -- R x B swarms of at most
``blocks`` dimensions, advanced together in one batch. A fish swarm contracts far faster in 6
dimensions than in 24 (:mod:`recal.solve.nafsa`'s table: 4e-5 of Visual after 60 iterations in
6 dimensions, 6e-2 in 15), and the batch costs as many objective calls as one joint swarm.

H's cross terms between blocks (finite-difference error, the slews' linearisation point) are
dropped: each block is searched with the others at the run's base, a Jacobi step, and the next
cycle's model, taken at the runs' new mean, starts from what is left. The combined step is
judged on the full quadratic, cross terms included, and each cycle on the exact objective.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from recal.solve.swarm import SwarmConfig


class BlockLayout(NamedTuple):
    """``blocks`` blocks of ``size`` directions covering ``d`` (the last ``pad`` are padding)."""

    d: int
    blocks: int
    size: int

    @property
    def pad(self) -> int:
        return self.blocks * self.size - self.d


def block_layout(d: int, most: int) -> BlockLayout:
    """The fewest blocks of at most ``most`` directions, of equal size (least padding)."""
    blocks = -(-d // max(1, most))
    return BlockLayout(d, blocks, -(-d // blocks))


class BlockSearch(NamedTuple):
    step: np.ndarray  # (R, d) best step per run, in phase coordinates
    objective: np.ndarray  # (R,) the full quadratic at that step
    history: np.ndarray  # (R, iterations + 1) best-so-far, summed over the blocks
    evaluations: int  # block evaluations (each: one block's part of the objective)


def search_blocks(
    solver: Callable,
    config: SwarmConfig,
    rng: np.random.Generator,
    c: np.ndarray,
    g: np.ndarray,
    H: np.ndarray,
    visual: np.ndarray,
    most: int,
) -> BlockSearch:
    """Minimise ``c_r + g_r.x + x^T H x`` per run r (c (R,), g (R, d), H (d, d)) by one swarm
    per block of at most ``most`` directions, all in one batch, from x = 0 with initial Visual
    ``visual`` ((d,) or (R, d)).

    Padding directions (when d is not a multiple of the block size) take the mean curvature of
    the real ones, no gradient and the median Visual, so their optimum is where they start and
    they spread and contract as a real direction would; they are dropped from the answer."""
    R, d = g.shape
    lay = block_layout(d, most)
    B, k, pad = lay.blocks, lay.size, lay.pad
    curvature = float(np.mean(np.diag(H))) if d else 1.0
    Hp = np.zeros((B * k, B * k))
    Hp[:d, :d] = H
    Hp[np.arange(d, B * k), np.arange(d, B * k)] = curvature
    Hb = np.stack([Hp[i * k : (i + 1) * k, i * k : (i + 1) * k] for i in range(B)])  # (B, k, k)
    # swarms block-major (swarm b R + r: block b of run r), so a block's rows are contiguous in
    # every batch the solver evaluates (rows come in increasing swarm order)
    gb = np.pad(g, ((0, 0), (0, pad))).reshape(R, B, k).transpose(1, 0, 2).reshape(B * R, k)
    vis = np.broadcast_to(np.asarray(visual, float), (R, d))
    if pad:
        fill = np.broadcast_to(np.median(vis, axis=1, keepdims=True), (R, pad))
        vis = np.concatenate([vis, fill], axis=1)
    vis = vis.reshape(R, B, k).transpose(1, 0, 2).reshape(B * R, k)
    firsts = np.arange(1, B) * R  # first swarm of blocks 1 .. B-1
    ones = np.ones(k)

    def f(X: np.ndarray, run: np.ndarray) -> np.ndarray:
        edges = (0, *np.searchsorted(run, firsts), run.size)
        gx = gb.take(run, axis=0)  # g + H x, row by row: g first, then each block's H x
        for b in range(B):  # a few blocks: one product each
            lo, hi = edges[b], edges[b + 1]
            gx[lo:hi] += X[lo:hi] @ Hb[b]
        gx *= X
        return gx @ ones  # faster than a sum over the short last axis

    res = solver(f, np.zeros((B * R, k)), vis, rng, config, with_runs=True)
    step = res.best_x.reshape(B, R, k).transpose(1, 0, 2).reshape(R, B * k)[:, :d]
    full = c + np.einsum("rd,rd->r", step, g + step @ H)
    history = c[:, None] + res.history.reshape(B, R, -1).sum(axis=0)
    return BlockSearch(step, full, history, res.evaluations)
