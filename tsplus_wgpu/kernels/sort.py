"""Host classes of shaders/sort/: the portable exclusive prefix sum and the stable LSD radix sort.
Block sizes and bits per pass are read from the WGSL (``shaders/common/scan.wgsl``, ``radix.wgsl``)."""

from __future__ import annotations

import numpy as np

from ..gpu import Stage
from ..gpu.context import GpuContext
from ..gpu.stage import Scratch


class ScanBlock(Stage):
    """Exclusive scan of each block of ``SCAN_BLOCK`` u32 in place; block totals to ``block_sums``."""
    stage = "scan_block"

    def __call__(self, enc, data, block_sums, n, profiler=None, label=None):
        """``data`` [n] u32 scanned per block in place; ``block_sums`` [ceil(n / SCAN_BLOCK)]. Returns the
        ScanParams uniform (scan_add reads the same one)."""
        sp = self.uniform("ScanParams", n=n)
        self.dispatch(enc, self.groups(n, self.const("SCAN_BLOCK")), dict(sp=sp, data=data, block_sums=block_sums),
                      profiler, label)
        return sp


class ScanAdd(Stage):
    """Adds ``block_offsets[b]`` to the ``SCAN_BLOCK`` values of block b."""
    stage = "scan_add"

    def __call__(self, enc, data, block_offsets, n, profiler=None, label=None, sp=None):
        sp = self.uniform("ScanParams", n=n) if sp is None else sp
        self.dispatch(enc, self.groups(n, self.const("SCAN_BLOCK")), dict(sp=sp, data=data, block_offsets=block_offsets),
                      profiler, label)


class RadixCount(Stage):
    """Per block of ``SORT_BLOCK`` keys, the histogram of one ``RADIX_BITS`` digit, digit-major."""
    stage = "radix_count"

    def __call__(self, enc, sp, keys, counts, num_blocks, profiler=None, label=None):
        """``sp``: SortParams uniform (n, shift, num_blocks); ``counts`` [RADIX * num_blocks]."""
        self.dispatch(enc, num_blocks, dict(sp=sp, keys=keys, counts=counts), profiler, label)


class RadixScatter(Stage):
    """Every key (and value) to its stable place for one digit, given the scanned counts."""
    stage = "radix_scatter"

    def __call__(self, enc, sp, keys_in, vals_in, offsets, keys_out, vals_out, num_blocks, profiler=None, label=None):
        self.dispatch(enc, num_blocks, dict(sp=sp, keys_in=keys_in, vals_in=vals_in, offsets=offsets,
                                            keys_out=keys_out, vals_out=vals_out), profiler, label)


class PrefixSum:
    """Exclusive prefix sum of u32 in place, any length: ``SCAN_BLOCK`` (1024) per workgroup,
    block sums scanned recursively and added back. ``record`` returns a buffer whose first
    element is the grand total."""

    def __init__(self, ctx: GpuContext, scratch: Scratch):
        self.ctx = ctx
        self.scratch = scratch
        self.block = ScanBlock(ctx)
        self.add = ScanAdd(ctx)

    def record(self, enc, data, n, level=0, profiler=None, label="scan"):
        nb = self.block.groups(n, self.block.const("SCAN_BLOCK"))
        sums = self.scratch.get(f"scan_sums_{level}", 4 * nb)
        sp = self.block(enc, data, sums, n, profiler, label)
        if nb == 1:
            return sums
        total = self.record(enc, sums, nb, level + 1, profiler, label)
        self.add(enc, data, sums, n, profiler, label, sp=sp)
        return total


class RadixSort:
    """Stable LSD radix sort of u32 keys with u32 values, ``RADIX_BITS`` (4) bits per pass,
    portable (no subgroups, no waiting on other workgroups). Only the low ``bits`` bits are sorted."""

    def __init__(self, ctx: GpuContext, scratch: Scratch, name="sort"):
        self.ctx = ctx
        self.scratch = scratch
        self.name = name
        self.count = RadixCount(ctx)
        self.scatter = RadixScatter(ctx)
        self.scan = PrefixSum(ctx, scratch)
        self.bits_per_pass = self.count.const("RADIX_BITS")
        self.radix = self.count.const("RADIX")
        self.block = self.count.const("SORT_BLOCK")

    def record(self, enc, keys, vals, n, bits=32, profiler=None):
        """Sorts (keys, vals) of length ``n``. Returns the (keys, vals) buffers holding the
        result: the inputs themselves after an even number of passes, else scratch."""
        passes = (int(bits) + self.bits_per_pass - 1) // self.bits_per_pass
        if n <= 1 or passes == 0:
            return keys, vals
        nb = self.count.groups(n, self.block)
        counts = self.scratch.get(f"{self.name}_counts", 4 * self.radix * nb)
        k_alt = self.scratch.get(f"{self.name}_keys_alt", 4 * n)
        v_alt = self.scratch.get(f"{self.name}_vals_alt", 4 * n)
        src = (keys, vals)
        dst = (k_alt, v_alt)
        for p in range(passes):
            sp = self.count.uniform("SortParams", n=n, shift=self.bits_per_pass * p, num_blocks=nb)
            self.count(enc, sp, src[0], counts, nb, profiler, self.name)
            self.scan.record(enc, counts, self.radix * nb, profiler=profiler, label=self.name)
            self.scatter(enc, sp, src[0], src[1], counts, dst[0], dst[1], nb, profiler, self.name)
            src, dst = dst, src
        return src

    def sort(self, keys, vals=None, bits=32):
        """Convenience for tests and tools: sort numpy arrays, return numpy arrays."""
        keys = np.ascontiguousarray(keys, dtype=np.uint32)
        n = keys.shape[0]
        vals = np.arange(n, dtype=np.uint32) if vals is None else np.ascontiguousarray(vals, dtype=np.uint32)
        kb = self.ctx.upload(keys, "sort_keys")
        vb = self.ctx.upload(vals, "sort_vals")
        enc = self.ctx.device.create_command_encoder()
        ko, vo = self.record(enc, kb, vb, n, bits)
        self.ctx.queue.submit([enc.finish()])
        return self.ctx.read(ko, np.uint32, n), self.ctx.read(vo, np.uint32, n)


def scan_numpy(ctx: GpuContext, values):
    """Run :class:`PrefixSum` on a numpy array (tests); returns (exclusive scan, total)."""
    values = np.ascontiguousarray(values, dtype=np.uint32)
    n = values.shape[0]
    buf = ctx.upload(values, "scan_data")
    scan = PrefixSum(ctx, Scratch(ctx))
    enc = ctx.device.create_command_encoder()
    total = scan.record(enc, buf, n)
    ctx.queue.submit([enc.finish()])
    return ctx.read(buf, np.uint32, n), int(ctx.read(total, np.uint32, 1)[0])
