"""Topology during training: the pure operations on a :class:`~..state.VertexState`
(:mod:`.ops`), the strategy that schedules them (:class:`.topology.TopologyStrategy`) and its
densification cap (:func:`.cap.vertex_cap`)."""

from .ops import (choose_split, densify, new_vertex_count, projected_sizes, prune, remove_unused,
                  remove_unused_vertices, subdivide, triangle_areas)
from .cap import VertexCap, vertex_cap
from .topology import TopologyStrategy

__all__ = ["TopologyStrategy", "VertexCap", "vertex_cap", "triangle_areas", "projected_sizes",
           "remove_unused_vertices", "choose_split", "new_vertex_count", "subdivide", "remove_unused", "prune",
           "densify"]
