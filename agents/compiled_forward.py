"""The deterministic action of a trained policy network, as one compiled call.

``SB3AgentPolicy`` decides for every aircraft at every decision. Through NumPy, each
layer of the network cost a matrix product, a bias addition and an activation, each a
NumPy call of about a microsecond of dispatch, and the deep-sets extractor a dozen more
(reshapes, masks, pooling): 10-15 µs per decision for the MLPs and about 100 µs for the
deep-sets model when measured alone, several times the arithmetic (28 → 64 → 64 → 2 is
about 6,000 multiply-adds for four aircraft). Inside an episode, between flights of the
kernel, every one of those calls also ran from cold caches. Here the whole forward pass
is one numba call over weights packed into one float32 vector.

Arithmetic: float32 throughout like torch, each output a sum over the inputs in their
order, then the bias (neither torch nor NumPy's BLAS promise an order, so the result
agrees with SB3's ``predict`` to float32 rounding, ~1e-6, not bit for bit; the tests
check 1e-5). Every row of a batch is computed alone, so an aircraft's action is the same
bit for bit whatever the other rows are. Compiled without fast-math: no reassociation.

Scratch: each model's forward pass keeps its buffers between calls (``agents.policy``).
That is safe across threads because these functions hold the GIL (no ``nogil``): two
threads never run one model's compiled pass at once.

Layout of a packed network (``pack_layers``): ``weights`` float32 holds, per layer, W^T
(D_in, D_out) row by row and then the bias (D_out,); ``layout`` int64 (L, 5) holds per
layer (D_in, D_out, offset of W^T, offset of the bias, activation: ``IDENTITY``,
``TANH`` or ``RELU``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numba import njit

from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

IDENTITY, TANH, RELU = 0, 1, 2
#: Output transforms of the action: clip to [-1, 1] (PPO's Gaussian mean) or tanh (SAC).
CLIP, SQUASH = 0, 1


def pack_layers(layers: Sequence[tuple[np.ndarray, np.ndarray, int]]) -> tuple[np.ndarray, np.ndarray]:
    """(weights float32 (P,), layout int64 (L, 5)) of dense layers [(W^T (D_in, D_out), bias
    (D_out,), activation)], each layer's input the previous one's output."""
    if not layers:
        raise ValueError("a network needs at least one layer")
    parts: list[np.ndarray] = []
    rows = []
    offset = 0
    previous_out = None
    for weight_t, bias, activation in layers:
        weight_t = np.asarray(weight_t, dtype=np.float32)
        bias = np.asarray(bias, dtype=np.float32).reshape(-1)
        d_in, d_out = weight_t.shape
        if bias.shape != (d_out,):
            raise ValueError(f"bias of shape {bias.shape} for a layer of {d_out} outputs")
        if previous_out is not None and d_in != previous_out:
            raise ValueError(f"a layer of {d_in} inputs after one of {previous_out} outputs")
        if activation not in (IDENTITY, TANH, RELU):
            raise ValueError(f"activation {activation!r}: allowed: {IDENTITY}, {TANH}, {RELU}")
        rows.append((d_in, d_out, offset, offset + d_in * d_out, activation))
        parts += [weight_t.reshape(-1), bias]
        offset += d_in * d_out + d_out
        previous_out = d_out
    return np.concatenate(parts).astype(np.float32), np.array(rows, dtype=np.int64)


def widest(layout: np.ndarray) -> int:
    """The largest layer width of a packed network (its scratch size)."""
    return int(max(layout[:, 0].max(), layout[:, 1].max()))


# A rational approximation of tanh (the one of the Eigen library for float32, evaluated
# here in float64): within 2.4e-7 of tanh on the whole line; 3 float32 ulps at most for |x| up
# to the clamp (7.905), 3.5 beyond it, where it returns its value at the clamp. libm's
# tanhf costs about 18 ns per call in a compiled loop and cannot be vectorized, which made
# the activations the dearest part of the forward pass; this one is a dozen multiply-adds.
_TANH_CLAMP = 7.90531110763549805
_TANH_P = (4.89352455891786e-03, 6.37261928875436e-04, 1.48572235717979e-05, 5.12229709037114e-08,
           -8.60467152213735e-11, 2.00018790482477e-13, -2.76076847742355e-16)
_TANH_Q = (4.89352518554385e-03, 2.26843463243900e-03, 1.18534705686654e-04, 1.19825839466702e-06)


@njit(cache=True, error_model="numpy", inline="always")
def tanh32(value: np.float32) -> np.float32:
    """tanh of a float32, to within 3 float32 ulps for |value| up to ``_TANH_CLAMP`` and 3.5
    beyond it (2.4e-7 everywhere; see ``_TANH_P``)."""
    x = min(max(np.float64(value), -_TANH_CLAMP), _TANH_CLAMP)
    x2 = x * x
    p = _TANH_P[6]
    p = p * x2 + _TANH_P[5]
    p = p * x2 + _TANH_P[4]
    p = p * x2 + _TANH_P[3]
    p = p * x2 + _TANH_P[2]
    p = p * x2 + _TANH_P[1]
    p = p * x2 + _TANH_P[0]
    q = _TANH_Q[3]
    q = q * x2 + _TANH_Q[2]
    q = q * x2 + _TANH_Q[1]
    q = q * x2 + _TANH_Q[0]
    return np.float32(x * p / q)


@njit(cache=True, error_model="numpy")
def _dense_row(x: np.ndarray, weights: np.ndarray, d_in: int, d_out: int, w_offset: int, b_offset: int,
               activation: int, out: np.ndarray) -> None:
    """out[:d_out] = activation(x[:d_in] @ W^T + b), float32."""
    for j in range(d_out):
        out[j] = np.float32(0.0)
    # Four inputs per pass over the outputs, added one after another as a pass per input
    # would (the same sum, bit for bit), with a quarter of the loads and stores of out.
    # Slices indexed from 0: an index known to be >= 0 carries no wraparound branch, so
    # LLVM vectorizes the loops over j (independent sums: no reassociation needed).
    k = 0
    while k + 4 <= d_in:
        x0, x1, x2, x3 = x[k], x[k + 1], x[k + 2], x[k + 3]
        base = w_offset + k * d_out
        w0 = weights[base : base + d_out]
        w1 = weights[base + d_out : base + 2 * d_out]
        w2 = weights[base + 2 * d_out : base + 3 * d_out]
        w3 = weights[base + 3 * d_out : base + 4 * d_out]
        for j in range(d_out):
            out[j] = (((out[j] + x0 * w0[j]) + x1 * w1[j]) + x2 * w2[j]) + x3 * w3[j]
        k += 4
    while k < d_in:
        xk = x[k]
        w_row = weights[w_offset + k * d_out : w_offset + (k + 1) * d_out]
        for j in range(d_out):
            out[j] += xk * w_row[j]
        k += 1
    bias = weights[b_offset : b_offset + d_out]
    for j in range(d_out):
        value = out[j] + bias[j]
        if activation == TANH:
            value = tanh32(value)
        elif activation == RELU:
            value = max(value, np.float32(0.0))
        out[j] = value


@njit(cache=True, error_model="numpy")
def _mlp_row(
    x: np.ndarray, weights: np.ndarray, layout: np.ndarray, buf_a: np.ndarray, buf_b: np.ndarray
) -> np.ndarray:
    """The packed network on one input row; returns the buffer that holds its output."""
    d_in, d_out, w_offset, b_offset, activation = layout[0]
    _dense_row(x, weights, d_in, d_out, w_offset, b_offset, activation, buf_a)
    for layer in range(1, layout.shape[0]):
        d_in, d_out, w_offset, b_offset, activation = layout[layer]
        if layer % 2 == 1:
            _dense_row(buf_a, weights, d_in, d_out, w_offset, b_offset, activation, buf_b)
        else:
            _dense_row(buf_b, weights, d_in, d_out, w_offset, b_offset, activation, buf_a)
    return buf_a if layout.shape[0] % 2 == 1 else buf_b


@njit(cache=True, error_model="numpy")
def _finish(row: np.ndarray, n: int, output: int, out: np.ndarray) -> None:
    for j in range(n):
        value = row[j]
        if output == SQUASH:
            value = tanh32(value)
        else:
            value = min(max(value, np.float32(-1.0)), np.float32(1.0))
        out[j] = value


@njit(cache=True, error_model="numpy")
def _all_finite(obs: np.ndarray) -> bool:
    """Whether every value of ``obs`` is finite (the compiled tanh clamps its argument, so
    a NaN would otherwise come out as a valid action)."""
    for b in range(obs.shape[0]):
        for k in range(obs.shape[1]):
            if not abs(obs[b, k]) < np.inf:
                return False
    return True


@njit(cache=True, error_model="numpy")
def mlp_actions(obs: np.ndarray, weights: np.ndarray, layout: np.ndarray, output: int,
                buf_a: np.ndarray, buf_b: np.ndarray, out: np.ndarray) -> bool:
    """Deterministic actions ``out`` (B, A) in [-1, 1] of a packed MLP on ``obs`` (B, D) float32;
    ``buf_a``, ``buf_b``: float32 scratch of ``widest(layout)``. Returns False, computing
    nothing, if ``obs`` holds a NaN or inf."""
    if not _all_finite(obs):
        return False
    n_out = layout[layout.shape[0] - 1, 1]
    for b in range(obs.shape[0]):
        row = _mlp_row(obs[b], weights, layout, buf_a, buf_b)
        _finish(row, n_out, output, out[b])
    return True


@njit(cache=True, error_model="numpy")
def deepsets_actions(
    obs: np.ndarray,
    n_own: int,
    n_slots: int,
    slot_size: int,
    own_weights: np.ndarray,
    own_layout: np.ndarray,
    phi_weights: np.ndarray,
    phi_layout: np.ndarray,
    head_weights: np.ndarray,
    head_layout: np.ndarray,
    output: int,
    buf_a: np.ndarray,
    buf_b: np.ndarray,
    features: np.ndarray,
    out: np.ndarray,
) -> bool:
    """Deterministic actions ``out`` (B, A) of a deep-sets policy (``agents.deepsets``): the
    features [own encoder(obs[:n_own]), masked mean and masked max of φ over the present
    neighbour slots (slot value 0 is the mask, 1.0 where a neighbour is present)] and the
    head (the policy MLP and the action layer) on them. ``features``: float32 scratch of
    3·hidden; ``buf_a``, ``buf_b``: of the widest layer of the three networks. Returns False,
    computing nothing, if ``obs`` holds a NaN or inf."""
    if not _all_finite(obs):
        return False
    hidden = own_layout[own_layout.shape[0] - 1, 1]
    n_out = head_layout[head_layout.shape[0] - 1, 1]
    for b in range(obs.shape[0]):
        row = obs[b]
        own = _mlp_row(row[:n_own], own_weights, own_layout, buf_a, buf_b)
        for j in range(hidden):
            features[j] = own[j]
            features[hidden + j] = np.float32(0.0)
            features[2 * hidden + j] = np.float32(-2.0)  # below tanh's range: never the max
        count = np.float32(0.0)
        for s in range(n_slots):
            start = n_own + s * slot_size
            if row[start] <= np.float32(0.0):
                continue  # no neighbour here: its encoding is masked out of both pools
            count += row[start]
            encoded = _mlp_row(row[start + 1 : start + slot_size], phi_weights, phi_layout, buf_a, buf_b)
            for j in range(hidden):
                value = encoded[j] * row[start]
                features[hidden + j] += value
                features[2 * hidden + j] = max(features[2 * hidden + j], value)
        for j in range(hidden):
            features[hidden + j] = features[hidden + j] / max(count, np.float32(1.0))
            if count <= np.float32(0.0):
                features[2 * hidden + j] = np.float32(0.0)
        head = _mlp_row(features, head_weights, head_layout, buf_a, buf_b)
        _finish(head, n_out, output, out[b])
    return True


__all__ = ["CLIP", "IDENTITY", "RELU", "SQUASH", "TANH", "deepsets_actions", "mlp_actions", "pack_layers",
           "tanh32", "widest"]
