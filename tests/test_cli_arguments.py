"""Every `hypergs` subcommand, enumerated from the parser (so a new one is covered as soon as it is
registered), with bad values for each of its arguments: the exit status is 2, stderr is exactly one
line naming the command and the argument, there is no traceback and no file is left behind.

The bad values come from the argument's type (commands/options.py: each type lists values it must
refuse) or, for arguments with choices, a value outside them; so every argument that takes a value
must have one of those (test_every_argument_is_checked)."""
from __future__ import annotations

import argparse

import pytest

from hypergs_blender.commands import cli, options


def leaf_commands(parser=None, path=()) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """{("bench", "codec"): its parser, ...} for every (sub)command without subcommands."""
    parser = parser or cli.build_parser()
    found = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(leaf_commands(sub, path + (name,)))
    return found or {path: parser}


COMMANDS = leaf_commands()


def value_arguments(parser):
    return [a for a in parser._actions
            if a.nargs != 0 and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def good_value(action, tmp_path) -> str:
    """A value the argument accepts (creating the input it names)."""
    kind = action.type
    if action.choices is not None:
        return str(next(iter(action.choices)))
    if isinstance(kind, options.InputFile):
        path = tmp_path / f"input{kind.suffixes[0] if kind.suffixes else '.bin'}"
        path.touch()
        return str(path)
    if isinstance(kind, options.InputVideo):
        (tmp_path / "video.mp4").touch()
        return str(tmp_path / "video.mp4")
    if isinstance(kind, options.InputFolder):
        (tmp_path / "folder").mkdir(exist_ok=True)
        return str(tmp_path / "folder")
    if isinstance(kind, options.OutputFile):
        return str(tmp_path / f"output{kind.suffixes[0] if kind.suffixes else '.out'}")
    if isinstance(kind, options.OutputFolder):
        return str(tmp_path / "outputs")
    if isinstance(kind, options.Integer):
        return str(max(kind.low, 1))
    if isinstance(kind, options.Real):
        return str(min(kind.high, 1.0) / 2 if kind.high < float("inf") else 1.0)
    return {options.Resolution: "64x48", options.FrameSize: "crop64", options.GaussianRange: "16:64",
            options.PatchGrid: "2"}.get(
        type(kind), "x")


def bad_values(action) -> tuple[str, ...]:
    if action.choices is not None:
        return ("not-a-choice",) + (("abc",) if action.type is int else ())
    return action.type.refused


def command_line(path, parser, tested, value, tmp_path) -> list[str]:
    """argv with a good value for every required argument and `value` for `tested`."""
    argv = list(path)
    for action in value_arguments(parser):
        if action is tested:
            given = value
        elif action.required or (not action.option_strings and action.nargs not in ("?", "*")):
            given = good_value(action, tmp_path)
        else:
            continue
        argv += ([action.option_strings[-1]] if action.option_strings else []) + [given]
    return argv


def run(argv, capsys) -> tuple[int, list[str]]:
    try:
        cli.main(argv)
        code = 0
    except SystemExit as e:
        code = e.code
    return code, capsys.readouterr().err.splitlines()


def test_the_walk_sees_every_command():
    names = {" ".join(path) for path in COMMANDS}
    assert {"encode", "render", "eval", "fit", "train", "export", "info", "import-usd", "bench codec",
            "bench scale", "build-extension"} <= names
    assert len(names) >= 20


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=" ".join)
def test_every_argument_is_checked(path):
    unchecked = [argparse._get_action_name(a) for a in value_arguments(COMMANDS[path])
                 if not (isinstance(a.type, options.ArgType) or a.choices is not None)]
    assert not unchecked, f"give these a type from commands/options.py: {unchecked}"


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=" ".join)
def test_bad_values_are_one_line_and_leave_nothing(path, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    parser = COMMANDS[path]
    problems = []
    for action in value_arguments(parser):
        name = argparse._get_action_name(action)
        for value in bad_values(action):
            argv = command_line(path, parser, action, value, tmp_path)
            before = sorted(tmp_path.rglob("*"))
            code, err = run(argv, capsys)
            prefix = f"hypergs {' '.join(path)}: error: argument {name}: "
            if code != 2 or len(err) != 1 or not err[0].startswith(prefix) or sorted(tmp_path.rglob("*")) != before:
                problems.append(f"{argv}: exit {code}, stderr {err}")
    assert not problems, "\n".join(problems)


def _typed(parser, kinds):
    return [a for a in value_arguments(parser) if isinstance(a.type, kinds)]


@pytest.mark.parametrize("path", sorted(p for p, parser in COMMANDS.items() if _typed(parser, options.OutputFile)
                                        and _typed(parser, (options.InputFile, options.InputVideo))), ids=" ".join)
def test_an_output_that_is_an_input_is_refused(path, tmp_path, capsys, monkeypatch):
    """Every command with an output file and an input file: the output given as a link to the input."""
    monkeypatch.chdir(tmp_path)
    parser = COMMANDS[path]
    source = _typed(parser, (options.InputFile, options.InputVideo))[0]
    output = _typed(parser, options.OutputFile)[0]
    link = tmp_path / f"link{output.type.suffixes[0] if output.type.suffixes else '.out'}"
    link.symlink_to(good_value(source, tmp_path))
    argv = command_line(path, parser, output, str(link), tmp_path)
    if source.option_strings or not source.required and source.nargs == "?":
        argv += ([source.option_strings[-1]] if source.option_strings else []) + [good_value(source, tmp_path)]
    code, err = run(argv, capsys)
    assert code == 2 and len(err) == 1 and f"is the input {good_value(source, tmp_path)}" in err[0], err
