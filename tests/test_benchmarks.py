"""The benchmark commands' own checks (their figures are records, not tests:
experiments/BENCHMARKS.md)."""

import pytest

from slotv_jax.benchmarks import startup


@pytest.mark.parametrize(
    "argv, piece",
    [(["--repeats", "0"], "--repeats 0: expected at least 1"),
     (["--commands", "train,nope"], "--commands 'train,nope': expected some of train,")],
)  # fmt: skip
def test_the_startup_benchmark_refuses_bad_flags_before_starting_anything(argv, piece, capsys):
    with pytest.raises(SystemExit) as e:
        startup.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and piece in err and "Traceback" not in err
