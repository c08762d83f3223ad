"""The output rule, the readers and the CLI error style (slotv_jax.core.fileio, slotv_jax.cli)."""

import os
import zipfile

import numpy as np
import pytest

from slotv_jax.core import cli, fileio


def _ours(p):
    return (p / "marker.json").is_file()


def test_output_dir_rule(tmp_path):
    assert fileio.check_output_dir(tmp_path / "new" / "deeper", ours=_ours) == "new"
    (tmp_path / "empty").mkdir()
    assert fileio.check_output_dir(tmp_path / "empty", ours=_ours) == "new"
    user = tmp_path / "user"
    user.mkdir()
    (user / "thesis.tex").write_text("mine")
    for kw in ({}, {"resume": True}, {"overwrite": True}):
        with pytest.raises(fileio.OutputError, match=r"--out .*user: a non-empty directory"):
            fileio.check_output_dir(user, ours=_ours, **kw)
    ours = tmp_path / "ours"
    ours.mkdir()
    (ours / "marker.json").write_text("{}")
    with pytest.raises(fileio.OutputError, match=r"--resume to continue it.*--overwrite"):
        fileio.check_output_dir(ours, ours=_ours, resume_hint="pass --resume to continue it")
    with pytest.raises(fileio.OutputError) as e:  # a command without --resume offers none
        fileio.check_output_dir(ours, ours=_ours)
    assert str(e.value).endswith(
        "pass --overwrite to replace it, or choose another --out to keep it"
    )
    assert fileio.check_output_dir(ours, ours=_ours, resume=True) == "resume"
    assert fileio.check_output_dir(ours, ours=_ours, resume=True, overwrite=True) == "overwrite"
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(fileio.OutputError, match="is a file, not a directory"):
        fileio.check_output_dir(f, ours=_ours, overwrite=True)
    with pytest.raises(fileio.OutputError, match=r"file, not a directory"):
        fileio.check_output_dir(f / "sub", ours=_ours)
    assert f.read_text() == "x" and (user / "thesis.tex").read_text() == "mine"
    assert sorted(os.listdir(tmp_path)) == ["empty", "file", "ours", "user"]  # no probe left


def test_output_file_rule(tmp_path):
    assert fileio.check_output_file(tmp_path / "a.npz") == "new"
    (tmp_path / "a.npz").write_bytes(b"user")
    with pytest.raises(fileio.OutputError, match="exists; pass --overwrite"):
        fileio.check_output_file(tmp_path / "a.npz")
    assert fileio.check_output_file(tmp_path / "a.npz", overwrite=True) == "overwrite"
    with pytest.raises(fileio.OutputError, match="is a directory"):
        fileio.check_output_file(tmp_path, overwrite=True)
    with pytest.raises(fileio.OutputError, match="file, not a directory"):
        fileio.check_output_file(tmp_path / "a.npz" / "b.npz")


def test_report_files_resume_only_from_our_results(tmp_path):
    """A results document the command resumes from must be ours: somebody else's file of
    that name is refused and left as it was; the reports beside it are regenerated."""
    names = ["x_results.json", "x.md"]
    ours = {"x_results.json": lambda p: p.read_text().startswith("{")}
    fileio.check_output_files(tmp_path / "new", names, ours=ours)  # nothing there yet
    (tmp_path / "x.md").write_text("an old report")
    (tmp_path / "x_results.json").write_text("my notes")
    with pytest.raises(fileio.OutputError, match=r"x_results\.json exists and is not ours"):
        fileio.check_output_files(tmp_path, names, ours=ours)
    assert (tmp_path / "x_results.json").read_text() == "my notes"
    (tmp_path / "x_results.json").write_text("{}")
    fileio.check_output_files(tmp_path, names, ours=ours)
    # beside: a report of that name with no results document of ours next to it is not ours
    fileio.check_output_files(tmp_path, names, ours=ours, beside=names[0])  # ours beside it
    (tmp_path / "x_results.json").unlink()
    with pytest.raises(fileio.OutputError, match=r"x\.md exists beside no x_results\.json"):
        fileio.check_output_files(tmp_path, names, ours=ours, beside=names[0])
    assert (tmp_path / "x.md").read_text() == "an old report"
    fileio.check_output_files(tmp_path, names, ours=ours)  # without beside: regenerated


def test_an_output_is_never_one_of_the_inputs(tmp_path):
    """``check_not_input``: the same file by any name (relative, through '..', a symbolic
    or hard link) is refused, ``--overwrite`` or not; a directory replaced whole may not
    hold an input. The input is left as it was."""
    a = tmp_path / "a.csv"
    a.write_text("trajectory,guess\n")
    inputs = {"--answers": a, "--goals": None}
    for out in (a, tmp_path / "sub" / ".." / "a.csv", os.path.relpath(a)):
        with pytest.raises(fileio.OutputError, match=r"is the input --answers .*a\.csv"):
            fileio.check_not_input(out, inputs)
    (tmp_path / "link.csv").symlink_to(a)
    os.link(a, tmp_path / "hard.csv")
    for name in ("link.csv", "hard.csv"):
        with pytest.raises(fileio.OutputError, match=r"--out .*: is the input --answers"):
            fileio.check_not_input(tmp_path / name, inputs)
    fileio.check_not_input(tmp_path / "b.npz", inputs)  # another file: fine
    fileio.check_not_input(tmp_path, inputs)  # a folder the files go into: fine
    with pytest.raises(fileio.OutputError, match=r"--out .*: holds the input --answers"):
        fileio.check_not_input(tmp_path, inputs, replaces_dir=True)
    with pytest.raises(fileio.OutputError, match=r"--ckpt .*: is the input --answers"):
        fileio.check_not_input(a, inputs, what="--ckpt", replaces_dir=True)
    assert a.read_text() == "trajectory,guess\n"


def test_output_suffix_must_match_the_format_written(tmp_path):
    assert fileio.check_output_file(tmp_path / "s.npz", suffix=".npz") == "new"
    assert fileio.check_output_file(tmp_path / "S.NPZ", suffix=".npz") == "new"
    for name, got in (("s.csv", "ending in '.csv'"), ("s", "without a suffix"),
                      ("s.npz.bak", "ending in '.bak'")):  # fmt: skip
        with pytest.raises(fileio.OutputError) as e:
            fileio.check_output_file(tmp_path / name, overwrite=True, suffix=".npz")
        assert str(e.value) == (
            f"--out {tmp_path / name}: expected a name ending in .npz (the format written), "
            f"got one {got}"
        )
    assert os.listdir(tmp_path) == []


def test_unwritable_places_are_caught_even_for_root(tmp_path):
    # chmod does not stop root; /proc and a read-only mount do, and so does a file parent
    with pytest.raises(fileio.OutputError, match="cannot write in /proc"):
        fileio.check_output_dir("/proc/slotv_out", ours=_ours)
    with pytest.raises(fileio.OutputError, match="cannot write in /proc"):
        fileio.check_output_file("/proc/labels.npz")


def test_replace_dir_keeps_a_complete_output(tmp_path):
    out = tmp_path / "ckpt"
    for text in ("first", "second"):
        tmp = fileio.temp_dir_beside(out)
        (tmp / "config.json").write_text(text)
        fileio.replace_dir(tmp, out)
        assert (out / "config.json").read_text() == text
    assert os.listdir(tmp_path) == ["ckpt"]  # no hidden .old / .tmp leftovers
    (tmp_path / "f").write_text("user")
    tmp = fileio.temp_dir_beside(tmp_path / "f")
    with pytest.raises(fileio.OutputError):
        fileio.replace_dir(tmp, tmp_path / "f")
    assert (tmp_path / "f").read_text() == "user"


def test_load_npz_names_every_kind_of_bad_file(tmp_path):
    good = tmp_path / "good.npz"
    np.savez(good, x=np.arange(500.0), y=np.ones(3, np.int32))
    got = fileio.load_npz(good)
    np.testing.assert_array_equal(got["x"], np.arange(500.0))
    raw = good.read_bytes()
    bad = tmp_path / "bad.npz"
    for n in (0, 2, 30, len(raw) // 2, len(raw) - 5):
        bad.write_bytes(raw[:n])
        with pytest.raises(ValueError, match=r"bad\.npz.*(empty|truncated)"):
            fileio.load_npz(bad)
    bad.write_text("x,y,z\n1,2,3\n")
    with pytest.raises(ValueError, match=r"not an \.npz file \(not a zip archive"):
        fileio.load_npz(bad)
    np.save(tmp_path / "a.npy", np.ones(3))
    with pytest.raises(ValueError, match=r"a \.npy array"):
        fileio.load_npz(tmp_path / "a.npy")
    with zipfile.ZipFile(bad, "w") as z:  # a zip whose member is not an array
        z.writestr("x.npy", b"garbage")
    with pytest.raises(ValueError, match=r"bad\.npz, array 'x'"):
        fileio.load_npz(bad)
    np.savez(bad, x=np.array([{}], dtype=object))
    with pytest.raises(ValueError, match="Python objects"):
        fileio.load_npz(bad)
    with pytest.raises(FileNotFoundError, match=r"missing\.npz"):
        fileio.load_npz(tmp_path / "missing.npz")


def test_read_json_and_text(tmp_path):
    p = tmp_path / "c.json"
    p.write_text('{"a": [1, 2')
    with pytest.raises(ValueError, match=r"c\.json, line 1, column \d+: .*truncated"):
        fileio.read_json(p)
    p.write_text('[{"a": 1, "a": 2}]')
    assert fileio.read_json(p) == [{"a": 2}]  # json's own rule: the last key wins
    pairs = fileio.read_json(p, object_pairs_hook=list)  # a hook sees every pair
    assert pairs == [[("a", 1), ("a", 2)]]
    p.write_bytes(b"\xef\xbb\xbftrajectory,x\n1,2\n")
    assert fileio.read_text(p).startswith("trajectory,x")
    p.write_bytes(b"a,b\n1,2\n3,\xe9\n")
    with pytest.raises(ValueError, match=r"c\.json, line 3: byte 0xe9 is not UTF-8"):
        fileio.read_text(p)


def test_read_json_names_a_file_python_cannot_parse(tmp_path):
    """Nesting 100,000 deep (json raises RecursionError) and an integer of 5,000 digits
    (int() refuses it): ValueError naming the file, also where a command only asks whether
    a results document is ours; a hook's own error passes through."""
    deep, long = tmp_path / "deep.json", tmp_path / "long.json"
    deep.write_text('{"a": ' * 100_000 + "1" + "}" * 100_000)
    long.write_text('{"a": ' + "1" * 5000 + "}")
    with pytest.raises(ValueError, match=rf"^{deep}: not a JSON document .*nested too deeply"):
        fileio.read_json(deep)
    with pytest.raises(ValueError, match=rf"^{long}: not a JSON document .*5000 characters"):
        fileio.read_json(long)
    assert not fileio.is_json_object_with(deep, ["a"])
    with pytest.raises(fileio.OutputError, match=r"deep\.json exists and is not ours"):
        ours = {"deep.json": lambda p: fileio.is_json_object_with(p, ["a"])}
        fileio.check_output_files(tmp_path, ["deep.json"], ours=ours)

    def refuse(pairs):
        raise ValueError("the hook's own message")

    plain = tmp_path / "plain.json"
    plain.write_text('{"a": 1}')
    with pytest.raises(ValueError, match=r"^the hook's own message$"):
        fileio.read_json(plain, object_pairs_hook=refuse)


def test_cli_command_reports_input_errors_in_one_line(capsys):
    @cli.command
    def bad_input(argv=None):
        raise cli.InputError("--n: expected an integer >= 1, got 0")

    @cli.command
    def missing(argv=None):
        open("/nonexistent/slotv.npz")

    @cli.command
    def bug(argv=None):
        raise TypeError("a real bug")

    with pytest.raises(SystemExit) as e:
        bad_input([])
    assert e.value.code == 2
    assert capsys.readouterr().err == "error: --n: expected an integer >= 1, got 0\n"
    with pytest.raises(SystemExit):
        missing([])
    assert capsys.readouterr().err == "error: /nonexistent/slotv.npz: no such file or directory\n"
    with pytest.raises(TypeError, match="a real bug"):
        bug([])


# ------------------------------------ no command writes over one of its own inputs


def _refused(main, argv, capsys, *pieces):
    """``main(argv)`` exits with code 2 and prints one line ``error: ...`` with ``pieces``."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for piece in pieces:
        assert piece in err, (piece, err)


def _motions(path):
    """A labelers/render input .npz: 2 motions of 5 points (joint angles too), 2 goals."""
    from slotv_jax.robot import kinematics

    xyz = np.linspace([0.3, 0.0, 0.5], [0.5, 0.2, 0.03], 5)[None].repeat(2, 0)
    goals = np.zeros((8, 3))
    goals[:2] = [[0.5, 0.2, 0.025], [0.5, -0.2, 0.025]]
    q = np.broadcast_to(np.asarray(kinematics.Q_HOME), (2, 5, 7))
    with open(path, "wb") as f:  # any name: np.savez(path) would add .npz
        np.savez(f, xyz=xyz, goals=goals, goal_mask=np.arange(8) < 2, q=q)
    return path.read_bytes()


def test_labelers_never_write_over_their_input(tmp_path, capsys):
    """``--in x.npz --out x.npz --overwrite`` replaced the input with the labels, and
    ``--out labels.csv`` wrote an .npz under a .csv name."""
    from slotv_jax.labelers import cli as labelers_cli

    raw = _motions(tmp_path / "x.npz")
    for out in ("x.npz", "./sub/../x.npz"):
        _refused(labelers_cli.main, ["--in", str(tmp_path / "x.npz"), "--out",
                 str(tmp_path / out), "--overwrite", "--quiet"], capsys,
                 "is the input --in")  # fmt: skip
    _refused(labelers_cli.main, ["--in", str(tmp_path / "x.npz"), "--out",
             str(tmp_path / "labels.csv"), "--quiet"], capsys,
             "labels.csv: expected a name ending in .npz")  # fmt: skip
    assert (tmp_path / "x.npz").read_bytes() == raw
    assert sorted(os.listdir(tmp_path)) == ["x.npz"]


def test_render_never_writes_over_its_input(tmp_path, capsys):
    """The output's suffix picks the format, so an input named ``clip.png`` was replaced by
    its own picture."""
    from slotv_jax.render import cli as render_cli

    raw = _motions(tmp_path / "clip.png")
    _refused(render_cli.main, ["--npz", str(tmp_path / "clip.png"), "--out",
             str(tmp_path / "clip.png"), "--overwrite", "--quiet"], capsys,
             f"--out {tmp_path / 'clip.png'}: is the input --npz")  # fmt: skip
    assert (tmp_path / "clip.png").read_bytes() == raw


def test_train_never_replaces_a_checkpoint_that_holds_its_study(tmp_path, capsys):
    """``--study ckpt/s.npz --out ckpt --overwrite`` swapped the checkpoint folder, study
    file and all, for the new checkpoint."""
    from slotv_jax.train import cli as train_cli

    ckpt = tmp_path / "ckpt"
    (ckpt / "state").mkdir(parents=True)  # a checkpoint of ours (its marker files)
    (ckpt / "config.json").write_text("{}")
    (ckpt / "s.npz").write_bytes(b"the study")
    base = ["--method", "slotv", "--epochs", "1", "--overwrite"]
    _refused(train_cli.main, ["--study", str(ckpt / "s.npz"), "--out", str(ckpt), *base],
             capsys, f"--out {ckpt}: holds the input --study")  # fmt: skip
    _refused(train_cli.main, ["--study", str(ckpt / "s.npz"), "--out", str(ckpt / "s.npz"),
             *base], capsys, "is the input --study")  # fmt: skip
    assert (ckpt / "s.npz").read_bytes() == b"the study"


def test_study_export_and_stimuli_never_write_over_their_inputs(tmp_path, capsys):
    from slotv_jax.study import cli as study_cli
    from slotv_jax.webstudy.stimuli import MANIFEST

    out = tmp_path / "tables"
    out.mkdir()
    (out / "answers.csv").write_bytes(b"the database")  # a --db that export would replace
    _refused(study_cli.main, ["export", "--db", str(out / "answers.csv"), "--out", str(out),
             "--overwrite"], capsys, "is the input --db")  # fmt: skip
    assert (out / "answers.csv").read_bytes() == b"the database"
    stim = tmp_path / "stimuli"
    stim.mkdir()
    (stim / MANIFEST).write_text("{}")  # an earlier set of ours, replaced with --overwrite
    (stim / "s.npz").write_bytes(b"the study")
    _refused(study_cli.main, ["stimuli", "--study", str(stim / "s.npz"), "--out", str(stim),
             "--overwrite"], capsys, f"--out {stim}: holds the input --study")  # fmt: skip
    assert (stim / "s.npz").read_bytes() == b"the study"
