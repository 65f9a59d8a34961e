import pytest


@pytest.fixture(params=[None, 2], ids=["grid-1d", "grid-2d"])
def max_dim(request, ctx, monkeypatch):
    """Also run with at most 2 workgroups per dimension: the 2-D grid that more than 65535
    workgroups take (and its overshoot workgroups), at a size lavapipe runs quickly."""
    if request.param is not None:
        monkeypatch.setitem(ctx.limits, "max-compute-workgroups-per-dimension", request.param)
    return request.param
