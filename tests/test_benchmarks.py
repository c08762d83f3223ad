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


def test_the_render_benchmark_runs_and_checks_its_shared_clips(capsys):
    """At a tiny size (a few seconds): every row printed, and the clips of one motion drawn
    each moment once equal those drawn alone (the benchmark asserts it)."""
    from slotv_jax.benchmarks import render

    assert render.main(["--size", "64x36", "--frames", "6", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "each moment drawn once (study stimuli)" in out and out.count("\n| ") == 11, out
