"""The predictive's evaluation in blocks of draws and rows gives what one call gives."""

import jax.numpy as jnp
import numpy as np
import pytest

from calnet.predict import DRAW_BLOCK, ROW_BLOCKS, _blocked


@pytest.mark.parametrize("n_draws, n_rows", [(1, 1), (DRAW_BLOCK, ROW_BLOCKS[0]),
                                             (2 * DRAW_BLOCK + 3, 70),
                                             (7, 2 * ROW_BLOCKS[-1] + 5)])
def test_blocks_match_one_call(n_draws, n_rows):
    rng = np.random.default_rng(n_draws + n_rows)
    a, b = rng.normal(size=(n_draws, 2)), rng.normal(size=n_rows)
    eps = rng.normal(size=(n_draws, n_rows))
    calls = []

    def fn(draws, rows, both):
        calls.append((draws["a"].shape, rows["x"].shape, both["e"].shape))
        mean = draws["a"][:, :1] * rows["x"][None, :] + both["e"]
        return mean, jnp.exp(draws["a"][:, 1:]) + 0.0 * rows["x"][None, :]

    mean, var = _blocked(fn, n_draws, n_rows, {"a": jnp.asarray(a)}, {"x": jnp.asarray(b)},
                         {"e": jnp.asarray(eps)})
    np.testing.assert_allclose(mean, a[:, :1] * b[None, :] + eps, rtol=1e-14)
    np.testing.assert_allclose(var, np.broadcast_to(np.exp(a[:, 1:]), (n_draws, n_rows)))
    # every call has one of the block shapes: the compiled program is shared
    rows_block = next((r for r in ROW_BLOCKS if n_rows <= r), ROW_BLOCKS[-1])
    assert {c for c in calls} == {((DRAW_BLOCK, 2), (rows_block,), (DRAW_BLOCK, rows_block))}
    assert len(calls) == -(-n_draws // DRAW_BLOCK) * -(-n_rows // rows_block)
