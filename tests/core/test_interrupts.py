"""sonarsim.core.interrupts: Ctrl-C held back during a block, delivered at its end."""

from __future__ import annotations

import os
import signal

import pytest

from sonarsim.core.interrupts import signals_deferred


def test_ctrl_c_inside_the_block_is_delivered_at_its_end():
    reached_end_of_block = False
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            try:  # a library that swallows everything, as trimesh's optional imports do
                sum(range(10_000))
            except BaseException:  # noqa: BLE001
                pytest.fail("the signal reached the block")
            reached_end_of_block = True
    assert reached_end_of_block
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_previous_handlers_get_each_signal_once_and_are_restored():
    seen = []

    def record(signum, frame):
        seen.append(signum)

    before = signal.signal(signal.SIGTERM, record)
    try:
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == []
        assert seen == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGTERM) is record
    finally:
        signal.signal(signal.SIGTERM, before)


def test_nothing_pending_changes_nothing():
    with signals_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# --- Ctrl-C while the command starts -----------------------------------------------------------

import subprocess  # noqa: E402
import sys  # noqa: E402

from sonarsim.core.interrupts import STARTING_MESSAGE, command_is_starting  # noqa: E402


@pytest.mark.parametrize("orig_argv, argv0, expected", [
    (["python", "-m", "sonarsim", "render"], "-m", True),
    (["python", "-X", "importtime", "-W", "error", "-m", "sonarsim"], "-m", True),
    (["python", "-msonarsim"], "-m", True),
    (["python", "-m", "sonarsim.cli.main", "presets"], "-m", True),
    (["python", "/venv/bin/sonarsim", "render"], "/venv/bin/sonarsim", True),  # the executable's script
    (["python", "-m", "pytest", "-m", "quick"], "-m", False),
    (["python", "-m", "sonarsim.dataset"], "-m", False),
    (["python", "-c", "import sonarsim", "-m", "sonarsim"], "-c", False),
    (["python", "script.py", "-m", "sonarsim"], "script.py", False),
    (["python"], "", False),
])
def test_the_command_is_told_by_its_command_line(orig_argv, argv0, expected):
    assert command_is_starting(orig_argv, argv0) is expected


def test_importing_sonarsim_elsewhere_leaves_ctrl_c_alone():
    import sonarsim  # noqa: F401

    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# A child that runs ``python -m sonarsim ARGS`` as the interpreter would (sys.orig_argv as it
# would be) and sends itself Ctrl-C at the moment MODULE starts to be imported: a deterministic
# stand-in for a Ctrl-C that lands there by chance on a loaded machine.
_CTRL_C_DURING_IMPORT = """
import os, runpy, signal, sys

class CtrlCAt:
    def find_spec(self, name, path=None, target=None):
        if name != {module!r}:
            return None
        sys.meta_path.remove(self)
        lost = False
        try:
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(1000))  # (a Python handler runs between bytecodes)
        except KeyboardInterrupt:
            if not {swallow!r}:
                raise
            lost = True
        if lost:  # what NumPy's C import did on a loaded machine: another error, the Ctrl-C gone
            raise ImportError('PyCapsule_Import could not import module "datetime"')
        return None

sys.meta_path.insert(0, CtrlCAt())
sys.orig_argv = [sys.executable, "-m", "sonarsim", *{args!r}]
sys.argv = ["-m", *{args!r}]
runpy._run_module_as_main("sonarsim")  # what ``python -m sonarsim`` calls
"""


@pytest.mark.parametrize("module, swallow", [
    ("typing", False),  # imported by sonarsim/__init__ after the hold
    ("argparse", False),  # by cli/main's first lines, before the command's handler (the failure under load)
    ("sonarsim.cli.render", False),  # by the parser
    ("numpy", True),  # by the parser (cli/calibrate), inside a C import that turns Ctrl-C into an ImportError
    ("sonarsim.config.presets", True),  # by the command as it runs (after the hold), likewise
    ("sonarsim.config.presets", False),
])
def test_ctrl_c_during_the_commands_imports_says_one_line(module, swallow):
    code = _CTRL_C_DURING_IMPORT.format(module=module, swallow=swallow, args=["presets"])
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.splitlines() == [STARTING_MESSAGE]
    assert proc.stdout == ""  # the presets table was not printed: the command stopped
