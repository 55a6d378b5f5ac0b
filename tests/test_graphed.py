"""GraphedCall: the function itself on the CPU; on a CUDA device, replays equal to the function
for any number of rows (padded rows never leak into the output)."""

import pytest
import torch

from acl3d.sim.graphed import GraphedCall


def _rowwise(a, b):
    """Row i of each output from row i of the inputs alone, as GraphedCall asks."""
    return (a * 2.0 + b[:, :1], torch.cumsum(b, dim=1).sin())


def test_on_the_cpu_it_is_the_function_itself():
    calls = []

    def fn(a):
        calls.append(a)
        return (a + 1,)

    a = torch.arange(6.0).reshape(3, 2)
    (out,) = GraphedCall(fn, torch.device("cpu"), rows_step=4)(a)
    assert calls == [a] and torch.equal(out, a + 1)


def test_inputs_of_other_row_counts_are_refused():
    call = GraphedCall(_rowwise, torch.device("cpu"))
    with pytest.raises(ValueError, match=r"inputs: rows \[3, 2\]"):
        call(torch.zeros((3, 2)), torch.zeros((2, 4)))


@pytest.mark.parametrize("name, value", [("rows_step", -1), ("max_rows", 0)])
def test_bad_arguments_are_named(name, value):
    with pytest.raises(ValueError, match=name):
        GraphedCall(_rowwise, torch.device("cpu"), **{name: value})


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_replays_equal_the_function_for_every_row_count():
    call = GraphedCall(_rowwise, torch.device("cuda"), rows_step=8, max_rows=32)
    g = torch.Generator(device="cuda").manual_seed(0)
    for k in (5, 8, 3, 17, 40, 5):  # 40 > max_rows: the function itself
        a = torch.rand((k, 3), generator=g, device="cuda", dtype=torch.float64)
        b = torch.rand((k, 4), generator=g, device="cuda", dtype=torch.float64)
        got, want = call(a, b), _rowwise(a, b)
        assert all(torch.equal(x, y) for x, y in zip(got, want))
    assert sorted(key[0] for key in call._graphs) == [8, 24]  # 5, 8, 3 -> 8 rows; 17 -> 24
