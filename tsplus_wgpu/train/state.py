"""The trainer's per-vertex state on the host: :class:`VertexState`.

One row per vertex in every per-vertex array (the parameters and the Adam moments of each),
the triangles that index them, and the topology's per-triangle running max blending weight.
:meth:`~.trainer.Trainer.read_state` reads it from the device and
:meth:`~.trainer.Trainer.set_state` re-creates the device buffers from it; the topology
operations (:mod:`.strategy.ops`) map a state to a new one.

A checkpoint keeps the SH and their moments planar (``[K, N, 3]``, band-major) and every moment
flat (:meth:`VertexState.from_flat` reads that); the device keeps the SH as the renderer reads
them, ``[N, K, 3]``, with flat moments (:meth:`VertexState.flat`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

#: the trainer's parameter groups (one device buffer and one pair of Adam moments each)
PARAMS = ("positions", "sh", "logits")
#: per-vertex arrays of the state, in field order (row i belongs to vertex i)
VERTEX_KEYS = ("positions", "sh", "logits", "exp_avg_positions", "exp_avg_sq_positions", "exp_avg_sh",
               "exp_avg_sq_sh", "exp_avg_logits", "exp_avg_sq_logits")
MOMENTS = ("exp_avg", "exp_avg_sq")


@dataclass(frozen=True)
class VertexState:
    """Host arrays of a model under training. Operations return new states.

    Attributes:
        positions: ``[N, 3]``.  sh: ``[N, K, 3]``.  logits: ``[N]`` opacity logits.
        exp_avg_<p>, exp_avg_sq_<p>: Adam's first and second moments of parameter ``p``, same
            shapes as ``p``.
        triangles: ``[M, 3]`` int64 vertex indices.
        max_weight: ``[M]`` float32 running max blending weight of each triangle (None: zeros).
        groups: ``[M]`` int8 group of each triangle (None: all ordinary; ``shell.SHELL``: the
            background shell, which the opacity and weight prunes leave alone). Children of a
            split triangle inherit its group.
    """

    positions: np.ndarray
    sh: np.ndarray
    logits: np.ndarray
    exp_avg_positions: np.ndarray
    exp_avg_sq_positions: np.ndarray
    exp_avg_sh: np.ndarray
    exp_avg_sq_sh: np.ndarray
    exp_avg_logits: np.ndarray
    exp_avg_sq_logits: np.ndarray
    triangles: np.ndarray
    max_weight: np.ndarray | None = None
    groups: np.ndarray | None = None

    @property
    def n(self):
        """Vertices."""
        return int(self.positions.shape[0])

    @property
    def m(self):
        """Triangles."""
        return int(self.triangles.shape[0])

    @property
    def k(self):
        """SH coefficients per colour channel."""
        return int(self.sh.shape[1])

    def vertex_arrays(self):
        """``{key: [N, ...]}`` of every per-vertex array."""
        return {key: getattr(self, key) for key in VERTEX_KEYS}

    def weights(self):
        """The max weights, zeros when unset: ``[M]`` float32."""
        return np.zeros(self.m, np.float32) if self.max_weight is None else self.max_weight

    def group_of(self):
        """The triangle groups, zeros (ordinary) when unset: ``[M]`` int8."""
        return np.zeros(self.m, np.int8) if self.groups is None else np.asarray(self.groups, np.int8)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_model(cls, positions, triangles, sh, logits, groups=None):
        """A fresh state: the parameters, zero moments, no max weights, ``groups`` [M]."""
        vertex = dict(positions=np.asarray(positions), sh=np.asarray(sh), logits=np.asarray(logits))
        for key in PARAMS:
            for mom in MOMENTS:
                vertex[f"{mom}_{key}"] = np.zeros(vertex[key].shape, np.float32)
        return cls(triangles=np.asarray(triangles, np.int64), groups=groups, **vertex)

    @classmethod
    def from_flat(cls, arrays, max_weight=None, groups=None):
        """From the device layout (what :meth:`~.trainer.Trainer.state_arrays` returns and a
        checkpoint stores): ``positions [N, 3]``, ``sh_planar [K, N, 3]``, ``logits [N]``,
        ``triangles``, flat ``exp_avg_<p>`` / ``exp_avg_sq_<p>``."""
        pos = arrays["positions"]
        n, k = pos.shape[0], arrays["sh_planar"].shape[0]
        vertex = dict(positions=pos, sh=arrays["sh_planar"].transpose(1, 0, 2), logits=arrays["logits"])
        for key, shape in (("positions", (n, 3)), ("sh", None), ("logits", (n,))):
            for mom in MOMENTS:
                arr = arrays[f"{mom}_{key}"]
                vertex[f"{mom}_{key}"] = arr.reshape(k, n, 3).transpose(1, 0, 2) if key == "sh" else arr.reshape(shape)
        return cls(triangles=np.asarray(arrays["triangles"], np.int64), max_weight=max_weight, groups=groups,
                   **vertex)

    def flat(self, key):
        """Parameter ``key`` and its moments in the device layout: ``(param, exp_avg,
        exp_avg_sq)`` float32, the parameter in its own shape (the SH ``[N, K, 3]``), moments
        flat in the same order."""
        m1, m2 = (getattr(self, f"{mom}_{key}") for mom in MOMENTS)
        return (np.ascontiguousarray(getattr(self, key), np.float32),
                np.ascontiguousarray(m1, np.float32).ravel(), np.ascontiguousarray(m2, np.float32).ravel())

    # ------------------------------------------------------------------ row operations
    def astype(self, dtype):
        """Every per-vertex array as ``dtype`` (triangles and max weights unchanged)."""
        return replace(self, **{key: np.asarray(a).astype(dtype) for key, a in self.vertex_arrays().items()})

    def take_triangles(self, rows):
        """The triangles ``rows`` (indices or a mask) with their max weights and groups; vertices
        unchanged."""
        mw = None if self.max_weight is None else self.max_weight[rows]
        gr = None if self.groups is None else np.asarray(self.groups)[rows]
        return replace(self, triangles=self.triangles[rows], max_weight=mw, groups=gr)

    def take_vertices(self, rows, triangles):
        """Vertex rows ``rows`` (new vertex i = old ``rows[i]``), indexed by ``triangles``."""
        return replace(self, triangles=np.asarray(triangles, np.int64),
                       **{key: a[rows] for key, a in self.vertex_arrays().items()})

    def append_vertices(self, rows, triangles, max_weight, groups=None):
        """``rows[key]`` appended to every per-vertex array, with new triangles, weights and
        groups."""
        return replace(self, triangles=np.asarray(triangles, np.int64), max_weight=max_weight, groups=groups,
                       **{key: np.concatenate([a, rows[key]]) for key, a in self.vertex_arrays().items()})


assert tuple(f.name for f in fields(VertexState))[:len(VERTEX_KEYS)] == VERTEX_KEYS

__all__ = ["VertexState", "VERTEX_KEYS", "PARAMS", "MOMENTS"]
