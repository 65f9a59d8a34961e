"""Benchmarks (commands, never tests), clients of the public API:

* :mod:`.measure` - the device's peak FMA rate, the blend kernels' FLOP counts, the blend timed
  on a trained model, a synthetic scene, median / min-max summaries;
* :mod:`.raster` - ``tsplus bench-raster``: the forward rasterizer per stage;
* :mod:`.backward` - ``tsplus bench-backward``: forward + backward per stage;
* :mod:`.plans`, :mod:`.runs`, :mod:`.report`, :mod:`.plots` - ``tsplus bench``: what runs on each
  scene, the runs on the real training loop (through :class:`~tsplus_wgpu.train.callbacks.TrainCallback`)
  and their cache, the report's tables and markdown, the figures.

The command-line options live in :mod:`tsplus_wgpu.cli.bench`.
"""
