"""slotv_jax.core.shapes: the padded batch sizes, by hand."""

import numpy as np
import pytest

from slotv_jax.core.shapes import bucket, pad_rows


def test_bucket_is_the_next_power_of_two_from_least():
    assert [bucket(n) for n in (0, 1, 8, 9, 16, 17, 1000)] == [8, 8, 8, 16, 16, 32, 1024]
    assert bucket(3, least=1) == 4 and bucket(1, least=1) == 1
    with pytest.raises(ValueError, match="n"):
        bucket(-1)


def test_pad_rows_repeats_the_first_row_and_keeps_the_rest():
    a = np.arange(6).reshape(3, 2)
    got = pad_rows(a, 5)
    assert got.shape == (5, 2)
    np.testing.assert_array_equal(got[:3], a)
    np.testing.assert_array_equal(got[3:], [[0, 1], [0, 1]])
    with pytest.raises(ValueError, match="size"):
        pad_rows(a, 2)
    with pytest.raises(ValueError, match="size"):
        pad_rows(a[:0], 4)
