"""The component table: which rows of the image stack each named image sums.

Every row of the stack is a distinct random image, so a component that sums the wrong rows (or
two components swapped in the assembly) shows.
"""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.renderer.components import (
    Components, assemble, component_table, frame_components, order_name, stack_rows,
)


def _stack(max_order, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 1.0, (stack_rows(max_order), 5, 4)).astype(np.float32)


def _expected(stack, max_order, bounces):
    """Each component from its definition (the module docstring's table)."""
    out = {"object": stack[0], "ground": stack[1], "single": stack[0] + stack[1]}
    for k in range(2, max_order + 1):
        out[{2: "double", 3: "triple"}.get(k, f"order{k}")] = stack[k]
    by_order = {1: stack[0] + stack[1], **{k: stack[k] for k in range(2, max_order + 1)}}
    out["total"] = sum(by_order[k].astype(np.float64) for k in bounces)
    return out


BOUNCES = [(1,), (2,), (1, 2), (1, 3), (2, 3), (1, 2, 3), (3, 1), (4,), (1, 4), (2, 5), (1, 2, 3, 4, 5), (5, 3)]


@pytest.mark.parametrize("max_order, bounces", [(k, b) for k in range(1, 6) for b in BOUNCES if max(b) <= k])
def test_assemble_sums_the_rows_each_component_names(max_order, bounces):
    stack = _stack(max_order, seed=max_order)
    got = assemble(stack, bounces, max_order)
    want = _expected(stack, max_order, bounces)
    assert list(got) == [c.name for c in component_table(max_order)]
    assert set(got) == set(want)
    for name, image in want.items():
        assert got[name].dtype == np.float32, name
        # float32 sums of up to five rows against float64: a few roundings.
        np.testing.assert_allclose(got[name], image, rtol=1e-6, err_msg=name)
    # The lazy mapping gives the same images.
    lazy = frame_components(stack, bounces, max_order)
    for name, image in want.items():
        np.testing.assert_allclose(lazy[name], image, rtol=1e-6, err_msg=name)


def test_the_order_names():
    assert [order_name(k) for k in range(1, 7)] == ["single", "double", "triple", "order4", "order5", "order6"]


@pytest.mark.parametrize("max_order, names", [
    (1, ["object", "ground", "single", "total"]),
    (2, ["object", "ground", "single", "double", "total"]),
    (3, ["object", "ground", "single", "double", "triple", "total"]),
    (5, ["object", "ground", "single", "double", "triple", "order4", "order5", "total"]),
])
def test_component_table_names_and_rows(max_order, names):
    table = component_table(max_order)
    assert [c.name for c in table] == names
    rows = {c.name: c.rows for c in table}
    assert rows["object"] == (0,) and rows["ground"] == (1,) and rows["single"] == (0, 1) and rows["total"] == ()
    for c in table:
        if c.order is not None and c.order >= 2:
            assert c.rows == (c.order,) and c.name == order_name(c.order)
    assert stack_rows(max_order) == max_order + 1


def test_single_rows_are_views_and_total_is_a_copy():
    stack = _stack(3)
    got = assemble(stack, (1, 2, 3), 3)
    assert np.shares_memory(got["double"], stack) and np.shares_memory(got["object"], stack)
    assert not np.shares_memory(got["total"], stack)
    total = assemble(stack, (2,), 3)["total"]
    assert not np.shares_memory(total, stack)


def test_components_are_formed_on_first_access():
    stack = _stack(4)
    calls = []

    def paths():
        calls.append(1)
        return {"O-ground-[objects]-ground-O": stack[3] * 2, "triple": stack[0]}  # a table name is not replaced

    c = frame_components(stack, (1, 2), 4, paths)
    assert not calls and "?" in repr(c)
    np.testing.assert_array_equal(c["double"], stack[2])
    np.testing.assert_allclose(c["single"], stack[0] + stack[1], rtol=1e-6)
    assert not calls  # table components do not form the path signatures
    assert "O-ground-[objects]-ground-O" in c
    assert calls == [1]
    names = list(c)
    assert names == ["object", "ground", "single", "double", "triple", "order4", "total",
                     "O-ground-[objects]-ground-O"]
    assert len(c) == 8 and c.signatures == ("O-ground-[objects]-ground-O",)
    np.testing.assert_array_equal(c["triple"], stack[3])
    assert "nothing" not in c
    with pytest.raises(KeyError):
        c["nothing"]
    assert calls == [1]  # formed once, kept


def test_components_without_signatures():
    stack = _stack(2)
    c = Components({"object": stack[0], "single": lambda: stack[0] + stack[1]})
    assert len(c) == 2 and list(c) == ["object", "single"] and c.signatures == ()
    np.testing.assert_array_equal(c["single"], stack[0] + stack[1])
    assert "O-[objects]-O" not in c
