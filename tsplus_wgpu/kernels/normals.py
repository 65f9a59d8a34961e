"""Host classes of shaders/normals/: the normal-encoding model, its backward chain and the
accumulation into the step's gradients. Twins: :mod:`tsplus_wgpu.reference.normals`."""

from __future__ import annotations

from ..gpu import Stage


class NormalModel(Stage):
    """Per triangle: three private corners (positions, SH DC ``n / (2 SH_C0)``, opacity ``o_T``)."""
    stage = "normal_model"

    def params(self, camera, num_triangles, num_vertices, weight=1.0):
        """The ``NormalParams`` uniform shared by the three normal kernels."""
        R, t = camera.R, camera.t
        return self.uniform("NormalParams", rot0=[*R[0], t[0]], rot1=[*R[1], t[1]], rot2=[*R[2], t[2]],
                            num_triangles=num_triangles, num_vertices=num_vertices, weight=float(weight))

    def __call__(self, enc, params, positions, triangles, opacity, corner_positions, corner_sh, corner_opacity, m,
                 profiler=None):
        self.dispatch(enc, self.groups(m), dict(np_=params, positions=positions, triangles=triangles, opacity=opacity,
                                            corner_positions=corner_positions, corner_sh=corner_sh,
                                            corner_opacity=corner_opacity), profiler)


class NormalBackward(Stage):
    """Per triangle: the normal render's corner gradients -> ``corner_vals [3M]`` vec4 (d position, d opacity)."""
    stage = "normal_backward"

    def __call__(self, enc, params, positions, triangles, opacity, v_corner_positions, v_corner_sh, v_corner_opacity,
                 corner_vals, m, profiler=None):
        self.dispatch(enc, self.groups(m), dict(np_=params, positions=positions, triangles=triangles, opacity=opacity,
                                            v_corner_positions=v_corner_positions, v_corner_sh=v_corner_sh,
                                            v_corner_opacity=v_corner_opacity, corner_vals=corner_vals), profiler)


class NormalAccumulate(Stage):
    """Per vertex: ``v_positions += weight * sums.xyz``, ``v_opacity += weight * sums.w``."""
    stage = "normal_accumulate"

    def __call__(self, enc, params, vertex_sums, v_positions, v_opacity, n, profiler=None):
        self.dispatch(enc, self.groups(n), dict(np_=params, vertex_sums=vertex_sums, v_positions=v_positions,
                                            v_opacity=v_opacity), profiler)
