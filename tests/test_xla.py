"""The XLA CPU setting applied by ``import slotv_jax`` (``slotv_jax.core.xla``).

``configure`` is tested on plain dicts; the import-time behaviour, which depends
on the state of a fresh interpreter, in subprocesses.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import pytest

from slotv_jax.core import xla as _xla

EMITTERS = "--xla_cpu_use_fusion_emitters=false"
WIDTH = "--xla_cpu_prefer_vector_width=512"
FLAGS = (EMITTERS, WIDTH)
FLAG = f"{EMITTERS} {WIDTH}"  # as they appear in XLA_FLAGS
OTHER = "--xla_force_host_platform_device_count=2"


def test_flag_constants():
    assert _xla.FLAGS == FLAGS
    assert _xla.OPT_OUT_VAR == "SLOTV_JAX_XLA_FLAGS"


@pytest.mark.parametrize("environ", [{}, {"XLA_FLAGS": ""}, {"XLA_FLAGS": "  "}])
def test_sets_flag_when_absent(environ):
    cfg = _xla.configure(environ)
    assert environ["XLA_FLAGS"] == FLAG
    assert cfg.applied == FLAGS
    assert cfg.xla_flags == FLAG


def test_appends_to_user_flags_without_overwriting():
    environ = {"XLA_FLAGS": f"{OTHER} --xla_dump_to=/tmp/x", "HOME": "/home/u"}
    cfg = _xla.configure(environ)
    assert environ["XLA_FLAGS"] == f"{OTHER} --xla_dump_to=/tmp/x {FLAG}"
    assert environ["HOME"] == "/home/u"
    assert cfg.applied == FLAGS
    assert cfg.xla_flags == environ["XLA_FLAGS"]


@pytest.mark.parametrize(
    "user",
    [
        "--xla_cpu_use_fusion_emitters=true --xla_cpu_prefer_vector_width=256",
        f"{OTHER} --xla_cpu_prefer_vector_width=128 --xla_cpu_use_fusion_emitters=false",
    ],
)
def test_respects_users_own_values(user):
    environ = {"XLA_FLAGS": user}
    cfg = _xla.configure(environ)
    assert environ == {"XLA_FLAGS": user}
    assert cfg.applied == ()
    assert cfg.xla_flags == user
    assert "already set" in cfg.reason


@pytest.mark.parametrize(
    ("user", "added"),
    [
        ("--xla_cpu_use_fusion_emitters=true", WIDTH),
        ("--xla_cpu_prefer_vector_width=256", EMITTERS),
    ],
)
def test_user_value_of_one_flag_keeps_the_other(user, added):
    environ = {"XLA_FLAGS": user}
    cfg = _xla.configure(environ)
    assert environ["XLA_FLAGS"] == f"{user} {added}"
    assert cfg.applied == (added,)
    assert "already set" in cfg.reason


def test_is_idempotent():
    environ = {"XLA_FLAGS": OTHER}
    _xla.configure(environ)
    second = _xla.configure(environ)
    assert environ["XLA_FLAGS"] == f"{OTHER} {FLAG}"
    assert second.applied == ()


@pytest.mark.parametrize("value", ["0", "false", "no", "off", "OFF", " False "])
def test_opt_out(value):
    environ = {"SLOTV_JAX_XLA_FLAGS": value, "XLA_FLAGS": OTHER}
    cfg = _xla.configure(environ)
    assert environ == {"SLOTV_JAX_XLA_FLAGS": value, "XLA_FLAGS": OTHER}
    assert cfg.applied == ()
    assert "SLOTV_JAX_XLA_FLAGS=0" in cfg.summary()
    empty = {"SLOTV_JAX_XLA_FLAGS": value}
    _xla.configure(empty)
    assert "XLA_FLAGS" not in empty


@pytest.mark.parametrize("value", ["1", "true", ""])
def test_other_opt_out_values_still_apply(value):
    environ = {"SLOTV_JAX_XLA_FLAGS": value}
    assert _xla.configure(environ).applied == FLAGS
    assert environ["XLA_FLAGS"] == FLAG


def test_summary_and_frozen_record():
    applied = _xla.configure({})
    assert FLAG in applied.summary() and "appended" in applied.summary()
    assert "SLOTV_JAX_XLA_FLAGS=0" in applied.summary()  # says how to opt out
    kept = _xla.configure({"XLA_FLAGS": f"{EMITTERS.replace('false', 'true')} {WIDTH}"})
    assert "left unchanged" in kept.summary()
    with pytest.raises(dataclasses.FrozenInstanceError):
        applied.applied = ()  # type: ignore[misc]


# --------------------------------------------------------------------------- fresh interpreters


def run_python(code: str, **env: str) -> list[str]:
    """Run ``code`` in a fresh interpreter whose environment has no XLA settings but ``env``."""
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "SLOTV_JAX_XLA_FLAGS")}
    out = subprocess.run(
        [sys.executable, "-c", code],
        env={**base, **env},
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return out.stdout.strip().splitlines()


IMPORT_AND_REPORT = (
    "import os, slotv_jax; "
    "print(os.environ.get('XLA_FLAGS', '<unset>')); "
    "print(slotv_jax.XLA_CONFIG.summary())"
)


def test_import_sets_flag_in_fresh_interpreter():
    flags, summary = run_python(IMPORT_AND_REPORT)
    assert flags == FLAG
    assert summary.startswith(f"slotv_jax: appended {FLAG} to XLA_FLAGS")


def test_import_keeps_user_flags_and_jax_reads_them():
    # JAX sees both flags: the user's (two host devices) and ours (XLA accepts its name).
    code = IMPORT_AND_REPORT + "; import jax; print(jax.device_count())"
    flags, summary, devices = run_python(code, XLA_FLAGS=OTHER, JAX_PLATFORMS="cpu")
    assert flags == f"{OTHER} {FLAG}"
    assert "appended" in summary
    assert devices == "2"


def test_import_respects_opt_out():
    flags, summary = run_python(IMPORT_AND_REPORT, SLOTV_JAX_XLA_FLAGS="0")
    assert flags == "<unset>"
    assert "left unchanged" in summary and "SLOTV_JAX_XLA_FLAGS=0" in summary


def test_import_after_jax_started_warns_and_changes_nothing():
    code = "\n".join(
        [
            "import os, warnings, jax",
            "jax.devices()",
            "with warnings.catch_warnings(record=True) as caught:",
            "    warnings.simplefilter('always')",
            "    import slotv_jax",
            "print(os.environ.get('XLA_FLAGS', '<unset>'))",
            "print(slotv_jax.XLA_CONFIG.applied)",
            "print([w.category.__name__ for w in caught])",
            "print(slotv_jax.XLA_CONFIG.summary())",
        ]
    )
    flags, applied, warned, summary = run_python(code, JAX_PLATFORMS="cpu")
    assert flags == "<unset>"
    assert applied == "()"
    assert warned == "['RuntimeWarning']"
    assert "left unchanged" in summary and "already initialised" in summary


# ------------------------------------------------- rule 4: flags this XLA does not know


def test_unsupported_flag_is_not_applied():
    environ = {"XLA_FLAGS": OTHER}
    cfg = _xla.configure(environ, supported=lambda flag: False)
    assert environ == {"XLA_FLAGS": OTHER}
    assert cfg.applied == ()
    assert "does not know" in cfg.summary()


def test_only_the_unsupported_flag_is_left_out():
    environ = {"XLA_FLAGS": OTHER}
    cfg = _xla.configure(environ, supported=lambda flag: flag == EMITTERS)
    assert environ == {"XLA_FLAGS": f"{OTHER} {EMITTERS}"}
    assert cfg.applied == (EMITTERS,)
    assert "does not know xla_cpu_prefer_vector_width" in cfg.reason


def test_probe_detects_unknown_and_known_flags():
    """XLA aborts on an unknown flag; the probe reports it instead of crashing us."""
    assert _xla.probe_flag("--xla_slotv_jax_no_such_flag=true") is False
    assert _xla.probe_flag(OTHER) is True


def test_probe_result_is_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = []
    monkeypatch.setattr(_xla, "probe_flag", lambda flag: calls.append(flag) or True)
    assert _xla.flag_supported(EMITTERS) is True
    assert _xla.flag_supported(EMITTERS) is True
    assert calls == [EMITTERS]
    assert _xla.flag_supported(WIDTH) is True  # each flag has its own entry
    assert calls == [EMITTERS, WIDTH]
    assert (tmp_path / "slotv_jax" / "xla_flags.json").exists()
    # A corrupt cache file is probed again and rewritten.
    (tmp_path / "slotv_jax" / "xla_flags.json").write_text("{oops")
    assert _xla.flag_supported(EMITTERS) is True
    assert len(calls) == 3
