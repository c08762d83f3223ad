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


def test_the_people_fits_benchmark_times_both_ways_and_refuses_bad_flags(capsys):
    """At a tiny size: a row per family, padded against the real slots."""
    from slotv_jax.benchmarks import people_fits

    argv = ["--families", "dragan_archetype,mlp", "--rows", "20", "--runs", "1", "--repeats", "1"]
    assert people_fits.main(argv) == 0
    out = capsys.readouterr().out
    assert "| dragan_archetype | 300 |" in out and "| mlp | 300 |" in out, out
    assert "| **every family** |" in out, out
    for bad, piece in ((["--families", "nope"], "--families: expected names of"),
                       (["--rows", "0"], "--rows: expected an int >= 1")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            people_fits.main(bad)
        err = capsys.readouterr().err
        assert e.value.code == 2 and piece in err and "Traceback" not in err
