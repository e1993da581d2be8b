"""Network pieces with a hand-written gradient: checked against XLA's own."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d5rl.agents.encoders import max_pool_3x3_s2


def reference_pool(x):
    return nn.max_pool(x, (3, 3), strides=(2, 2), padding="SAME")


@pytest.mark.parametrize("shape", [(4, 8, 8, 3), (2, 3, 16, 12, 5), (2, 7, 9, 2)])
def test_max_pool_matches_flax_values_and_gradients(shape):
    x = jax.random.normal(jax.random.PRNGKey(0), shape)
    out_shape = reference_pool(x).shape
    g = jax.random.normal(jax.random.PRNGKey(1), out_shape)
    np.testing.assert_array_equal(max_pool_3x3_s2(x), reference_pool(x))
    ours = jax.grad(lambda x: jnp.sum(max_pool_3x3_s2(x) * g))(x)
    ref = jax.grad(lambda x: jnp.sum(reference_pool(x) * g))(x)
    np.testing.assert_allclose(ours, ref, rtol=1e-6, atol=1e-6)


def test_max_pool_gradient_with_ties_goes_to_exactly_one_tap_per_window():
    x = jnp.zeros((1, 4, 4, 1))  # every window is all ties
    g = jnp.arange(1.0, 5.0).reshape(1, 2, 2, 1)
    dx = jax.grad(lambda x: jnp.sum(max_pool_3x3_s2(x) * g))(x)
    # the first tap of window (p, q) is pixel (2p, 2q): each gets its own window's gradient
    expected = np.zeros((4, 4))
    expected[::2, ::2] = np.arange(1.0, 5.0).reshape(2, 2)
    np.testing.assert_array_equal(dx[0, :, :, 0], expected)
