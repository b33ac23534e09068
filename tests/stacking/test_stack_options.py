# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""StackConfig: each stacking option declared once reaches stack, the live stack and the flags."""

import dataclasses

import numpy as np
import pytest

from astroalign_nd.cli.main import build_parser
from astroalign_nd.cli.options import _stack_kwargs
from astroalign_nd.options import fields_of
from astroalign_nd.stacking import LiveStack, StackConfig

_COMMANDS = {"stack": ["stack", "a.fits", "b.fits", "-o", "s.fits"],
             "live": ["watch", "folder", "-r", "a.fits", "--stack", "s.fits"]}


def _flags(argv):
    parser = build_parser()
    return {s for a in parser._subparsers._group_actions[0].choices[argv[0]]._actions
            for s in a.option_strings}


@pytest.mark.parametrize("user", ["stack", "live"])
def test_every_option_with_a_flag_is_on_its_users_commands(user):
    flags = _flags(_COMMANDS[user])
    for f in dataclasses.fields(StackConfig):
        flag = f.metadata["cli"].get("flag")
        if flag is not None:
            assert (flag in flags) == (f in fields_of(StackConfig, user)), (user, flag)


@pytest.mark.parametrize("user", ["stack", "live"])
def test_the_flags_defaults_are_the_configs(user):
    args = build_parser().parse_args(_COMMANDS[user])
    kwargs = _stack_kwargs(args, user)
    assert kwargs and StackConfig.from_keywords(user, kwargs)[0] == StackConfig()


def test_flags_reach_the_config_as_keywords():
    args = build_parser().parse_args(_COMMANDS["stack"] + [
        "--combine", "median", "--clip", "none", "--sigma-low", "2", "--memory-limit", "100",
        "--weights", "none", "--canvas", "union"])
    cfg, rest = StackConfig.from_keywords("stack", _stack_kwargs(args, "stack"))
    assert (cfg.method, cfg.clip, cfg.sigma_low, cfg.sigma_high) == ("median", None, 2.0, 3.0)
    assert (cfg.memory_limit, cfg.weights, cfg.canvas, rest) == (100e6, None, "union", {})
    live = build_parser().parse_args(_COMMANDS["live"] + ["--no-clip", "--sigma", "4"])
    cfg, _ = StackConfig.from_keywords("live", _stack_kwargs(live, "live"))
    assert (cfg.clip, cfg.sigma_low) == (None, 4.0)


@pytest.mark.parametrize("name", [f.name for f in dataclasses.fields(StackConfig)])
def test_every_option_is_checked_and_named(name):
    with pytest.raises((TypeError, ValueError), match=f"^{name} must be "):
        StackConfig(**{name: object()})


def test_each_user_refuses_the_others_options():
    with pytest.raises(TypeError, match="n_start: not an option of stack"):
        StackConfig.from_keywords("stack", {"n_start": 4})
    with pytest.raises(TypeError, match=r"method, nlow: not an option of a live stack"):
        LiveStack(np.zeros((8, 8)), method="median", nlow=2)
    with pytest.raises(ValueError, match="a live stack's clip must be one of 'sigma', None"):
        LiveStack(np.zeros((8, 8)), clip="minmax")
    with pytest.raises(TypeError, match="a live stack.s weights must be one of"):
        LiveStack(np.zeros((8, 8)), weights=[1.0])
    cfg, rest = StackConfig.from_keywords("live", {"n_start": 3, "fwhm": 2.0})
    assert cfg.n_start == 3 and rest == {"fwhm": 2.0}


@pytest.mark.parametrize("bad, message", [
    (["--drizzle", "0"], "--drizzle must be a finite number > 0"),
    (["--n-sources", "2"], "--n-sources must be an integer >= 3"),
    (["--bayer", "RGGB", "--canvas", "union"], "pass --canvas reference"),
])
def test_a_bad_option_is_the_one_line_of_a_stack(tmp_path, bad, message):
    """Refused before the banner and any work: nothing on standard output, one error line."""
    from _helpers import run_cli

    frames = [tmp_path / "a.fits", tmp_path / "b.fits"]
    for path in frames:
        path.write_bytes(b"")  # never read: the options are refused first
    code, stdout, err = run_cli("stack", *frames, "-o", tmp_path / "st.fits", *bad)
    assert code == 2 and stdout == ""
    (line,) = err.strip().splitlines()
    assert line.startswith("astroalign-nd: error: ") and message in line


@pytest.mark.parametrize("call", ["stack", "register_batch", "watch_folder"])
def test_a_callback_that_is_not_callable_is_refused_before_any_work(call, tmp_path):
    from astroalign_nd import register_batch, stack
    from astroalign_nd.stacking import watch_folder

    # Frames without stars: any work started would fail otherwise, and watch writes a stack.
    frames = [np.zeros((16, 16)), np.zeros((16, 16))]
    calls = {"stack": lambda: stack(frames, callback=3),
             "register_batch": lambda: register_batch(frames, frames[0], callback=3),
             "watch_folder": lambda: watch_folder(tmp_path, "a.fits", tmp_path / "s.fits",
                                                  callback=3)}
    with pytest.raises(TypeError, match="callback must be a function of .* or None; got 3"):
        calls[call]()
    assert not any(tmp_path.iterdir())
