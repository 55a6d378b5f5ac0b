"""Torch work replayed as CUDA graphs: a function of tensors captured once per input shape.

A batched reset on a GPU is hundreds of small torch operations (3D Terrain's fields, the first
observations). After the step's one host sync the GPU waits while the host launches them: about
5 ms of a 25 ms step at 16,384 worlds on an H200, two thirds of it in those two functions. Replayed
as a graph each costs one launch. On the CPU `GraphedCall` is the function itself.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from acl3d import validation


class GraphedCall:
    """`fn(*inputs) -> tuple of tensors`, replayed as a CUDA graph on a CUDA device.

    Every input has the same leading dimension k (rows). Inputs are copied into the graph's own
    buffers of `rows_step`-multiple rows (0: exactly k), so a few graphs serve every k up to
    `max_rows`; outputs are their first k rows, copied out of the graph's memory. The rows past k
    hold earlier calls' rows (valid inputs), so fn must compute each output row from the same
    row of the inputs alone, read other tensors only at fixed addresses (model fields, buffers
    made once), and never wait for the device (no `.item()`, `nonzero`, host data). Calls with
    more than `max_rows` rows, and every call on the CPU, run fn directly.
    """

    def __init__(
        self,
        fn: Callable[..., tuple[torch.Tensor, ...]],
        device: torch.device,
        rows_step: int = 0,
        max_rows: int | None = None,
    ):
        self.fn, self.device = fn, torch.device(device)
        self.rows_step = validation.integer("rows_step", rows_step, 0, 2**20)
        self.max_rows = None if max_rows is None else validation.integer("max_rows", max_rows, 1)
        self._graphs: dict[tuple, tuple] = {}  # shapes -> (input buffers, outputs, graph)
        self._pool = None  # one memory pool for this call's graphs (never replayed at once)

    def __call__(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        k = inputs[0].shape[0]
        rows = [t.shape[0] for t in inputs]
        if rows != [k] * len(inputs):
            raise ValueError(f"inputs: rows {rows}; every input needs the same leading dimension")
        if self.device.type != "cuda" or (self.max_rows is not None and k > self.max_rows):
            return tuple(self.fn(*inputs))
        padded = -(-k // self.rows_step) * self.rows_step if self.rows_step else k
        key = (padded, *((t.shape[1:], t.dtype) for t in inputs))
        if key not in self._graphs:
            self._graphs[key] = self._capture(inputs, padded)
        buffers, outputs, graph = self._graphs[key]
        for buffer, t in zip(buffers, inputs):
            buffer[:k].copy_(t)
        graph.replay()
        return tuple(out[:k].clone() for out in outputs)

    def _capture(self, inputs: tuple[torch.Tensor, ...], rows: int) -> tuple:
        """Buffers of `rows` rows (the first input row repeated: valid rows), fn run once on a
        side stream (its lazy allocations and library handles made outside the capture), then
        fn captured."""
        buffers = [t[:1].expand(rows, *t.shape[1:]).clone() for t in inputs]
        for buffer, t in zip(buffers, inputs):
            buffer[: len(t)].copy_(t)
        current = torch.cuda.current_stream(self.device)
        side = torch.cuda.Stream(self.device)
        side.wait_stream(current)
        with torch.cuda.stream(side):
            self.fn(*buffers)
        current.wait_stream(side)
        if self._pool is None:
            self._pool = torch.cuda.graph_pool_handle()
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=self._pool):
            outputs = tuple(self.fn(*buffers))
        return buffers, outputs, graph
