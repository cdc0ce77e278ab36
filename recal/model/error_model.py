"""Sensor models as ordered sets of terms, and the layout of the parameter vector.

A :class:`Model` composes the :class:`~recal.model.terms.Term` contributions of one triad into the
forward map (true input -> output) and its inverse (output -> true input), both batched over P
parameter vectors. A :class:`ParameterLayout` concatenates the parameters of one or two models
into a flat vector with names, so solvers only ever see arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recal.model.terms import Context, Term, seed_terms

#: Fixed-point steps for the inverse when a term depends on x (the accel K2 term is ~1e-5 / g,
#: so each step gains ~5 orders of magnitude; three is far below float64 resolution).
NONLINEAR_STEPS = 3


def inv3(A: np.ndarray) -> np.ndarray:
    """Inverse of a batch of 3x3 matrices (P, 3, 3) by the adjugate.

    Works on a component-major copy (9, P) so every operation runs over contiguous memory;
    several times faster than np.linalg.inv for this shape. Returns a (P, 3, 3) view.
    """
    T = A.transpose(1, 2, 0).reshape(9, -1)
    a, b, c, d, e, f, g, h, i = T
    co = np.empty_like(T)
    co[0] = e * i - f * h
    co[1] = c * h - b * i
    co[2] = b * f - c * e
    co[3] = f * g - d * i
    co[4] = a * i - c * g
    co[5] = c * d - a * f
    co[6] = d * h - e * g
    co[7] = b * g - a * h
    co[8] = a * e - b * d
    co /= a * co[0] + b * co[3] + c * co[6]
    return co.reshape(3, 3, -1).transpose(2, 0, 1)


def apply3(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product: A (P, 3, 3) times v (P, M, 3) -> (P, M, 3).

    Written out per component: for 3x3 matrices this is several times faster than einsum or
    matmul over the batch, and it is the hot path of every swarm evaluation.
    """
    out = np.empty(np.broadcast_shapes(v.shape, (A.shape[0], 1, 3)))
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    for i in range(3):
        out[..., i] = A[:, i, 0, None] * v0 + A[:, i, 1, None] * v1 + A[:, i, 2, None] * v2
    return out


def _apply3_components(A: np.ndarray, v: list[np.ndarray]) -> list[np.ndarray]:
    """A (P, 3, 3) applied to a vector given as three (P, M) components."""
    return [
        A[:, i, 0, None] * v[0] + A[:, i, 1, None] * v[1] + A[:, i, 2, None] * v[2]
        for i in range(3)
    ]


@dataclass(frozen=True)
class Model:
    """The error model of one triad: ``N = K_eff ⊙ [A x + Σ nonlinear(x) + Σ offset]``."""

    sensor: str
    terms: tuple[Term, ...]

    @classmethod
    def seed(cls, sensor: str, extra: Sequence[Term] = ()) -> Model:
        """The seed paper's model for ``sensor`` plus optional extra terms."""
        return cls(sensor, tuple(seed_terms(sensor)) + tuple(extra))

    def __post_init__(self) -> None:
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate terms in model: {names}")
        for t in self.terms:
            if t.sensor != self.sensor:
                raise ValueError(f"term {t.name} is for {t.sensor}, model is {self.sensor}")

    @property
    def size(self) -> int:
        return sum(t.size for t in self.terms)

    @property
    def needs(self) -> frozenset[str]:
        return frozenset().union(*(t.needs for t in self.terms))

    def with_terms(self, extra: Sequence[Term]) -> Model:
        return Model(self.sensor, self.terms + tuple(extra))

    def split(self, theta: np.ndarray) -> list[np.ndarray]:
        """(P, size) -> one (P, term.size) block per term."""
        out, k = [], 0
        for t in self.terms:
            out.append(theta[:, k : k + t.size])
            k += t.size
        return out

    def _parts(self, theta: np.ndarray, ctx: Context):
        P = theta.shape[0]
        gain: np.ndarray = np.ones((P, 1, 3))
        A = np.broadcast_to(np.eye(3), (P, 3, 3)).copy()
        offset: np.ndarray = np.zeros((P, 1, 3))
        nonlinear: list[tuple[Term, np.ndarray]] = []
        for t, p in zip(self.terms, self.split(theta), strict=True):
            s = t.scale(p, ctx)
            if s is not None:
                gain = gain * s
            m = t.matrix(p)
            if m is not None:
                A += m
            o = t.offset(p, ctx)
            if o is not None:
                offset = offset + o
            if type(t).nonlinear is not Term.nonlinear:
                nonlinear.append((t, p))
        return gain, A, offset, nonlinear

    def inverse_components(self, theta: np.ndarray, output: np.ndarray, ctx: Context) -> np.ndarray:
        """Outputs N (M, 3) -> the true input, component-major: shape (3, P, M).

        Component-major arrays keep the hot loop on contiguous memory; :meth:`inverse` stacks
        them. Inverts N = gain * (A x + h(x) + offset): x = A^-1 (N / gain - offset - h(x)).
        """
        gain, A, offset, nonlinear = self._parts(theta, ctx)
        Ainv = inv3(A)
        if not nonlinear and gain.shape[1] == 1 and offset.shape[1] == 1:
            # constant per parameter vector: x = B N + c with B = A^-1 diag(1/gain),
            # c = -A^-1 offset -- one (3P x 3) @ (3 x M) matrix product for the whole batch
            B = (Ainv / gain).transpose(1, 0, 2).reshape(-1, 3)  # rows (i, p); column j / gain_j
            c = -np.einsum("pij,pj->ip", Ainv, offset[:, 0, :])
            X = (B @ output.T).reshape(3, -1, output.shape[0])
            X += c[..., None]
            return X
        u = [output[None, :, i] / gain[..., i] - offset[..., i] for i in range(3)]
        x = _apply3_components(Ainv, u)
        for _ in range(NONLINEAR_STEPS if nonlinear else 0):
            hs = [t.nonlinear_components(p, x, ctx) for t, p in nonlinear]
            x = _apply3_components(Ainv, [u[i] - sum(h[i] for h in hs) for i in range(3)])
        return np.stack(x)

    def inverse(self, theta: np.ndarray, output: np.ndarray, ctx: Context) -> np.ndarray:
        """Outputs N (M, 3) -> true inputs x (P, M, 3) for each parameter vector in theta (P, size)."""
        return np.moveaxis(self.inverse_components(theta, output, ctx), 0, -1)

    def forward(self, theta: np.ndarray, x: np.ndarray, ctx: Context) -> np.ndarray:
        """True inputs x (M, 3) or (P, M, 3) -> outputs N (P, M, 3)."""
        gain, A, offset, nonlinear = self._parts(theta, ctx)
        x = np.broadcast_to(x, (theta.shape[0],) + x.shape[-2:])
        y = apply3(A, x) + offset
        for t, p in nonlinear:
            y = y + t.nonlinear(p, x, ctx)
        return gain * y


@dataclass(frozen=True)
class ParameterLayout:
    """Flat parameter vector over one or two models: names, blocks and typical magnitudes."""

    models: tuple[Model, ...]

    @property
    def size(self) -> int:
        return sum(m.size for m in self.models)

    @property
    def names(self) -> list[str]:
        return [f"{t.name}.{p}" for m in self.models for t in m.terms for p in t.params]

    def term_of(self) -> list[Term]:
        """The term owning each flat parameter."""
        return [t for m in self.models for t in m.terms for _ in t.params]

    def model_slices(self) -> dict[str, slice]:
        out, k = {}, 0
        for m in self.models:
            out[m.sensor] = slice(k, k + m.size)
            k += m.size
        return out

    def term_slices(self) -> dict[str, slice]:
        out, k = {}, 0
        for m in self.models:
            for t in m.terms:
                out[t.name] = slice(k, k + t.size)
                k += t.size
        return out

    def typical(self, theta_ref: np.ndarray) -> np.ndarray:
        """Typical change per parameter; scale factors are relative to the reference value."""
        typ = np.concatenate([np.asarray(t.typical, float) for m in self.models for t in m.terms])
        rel = np.array([t.relative_typical for t in self.term_of()])
        return np.where(rel, typ * np.maximum(np.abs(theta_ref), 1e-12), typ)

    def linearization_mask(self) -> np.ndarray:
        """True where the observability Jacobian sets the parameter to its neutral value."""
        return np.array([t.linearize_at_zero for t in self.term_of()])

    def neutral(self) -> np.ndarray:
        return np.concatenate([np.asarray(t.neutral, float) for m in self.models for t in m.terms])
