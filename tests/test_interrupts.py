import os
import signal

import pytest

from probvis.interrupts import deferred_interrupts


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_waits_for_the_next_safe_point(signum):
    """SIGHUP (a closed terminal) too: it killed a render mid-write, leaving a hidden temporary file."""
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupts() as check:
            os.kill(os.getpid(), signum)
            reached = True  # the handler only recorded it
            check()
    assert reached


def test_a_signal_inside_numbas_compiler_acts_at_once():
    """A first run compiles for minutes inside the render's deferral: SIGTERM 40 s in was acted on only after
    the compile (the process ran on for a minute)."""
    from numba.core.compiler_lock import global_compiler_lock

    reached = False
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupts():
            with global_compiler_lock:
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):  # the handler runs between bytecodes, within these
                    pass
                reached = True
    assert not reached


def test_a_second_signal_acts_at_once():
    """A plug-in stuck inside a batch kept the first Ctrl-C waiting for a safe point that never came."""
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupts():
            os.kill(os.getpid(), signal.SIGINT)
            reached.append(1)
            os.kill(os.getpid(), signal.SIGINT)
            reached.append(2)
    assert reached == [1]


def test_a_deferred_signal_whose_interrupt_was_swallowed_is_still_a_stop():
    """A study's SIGTERM (to the driver alone) while its report was written: the deferral's KeyboardInterrupt was
    swallowed by a library and the study ended with status 0; the stop is now remembered until the command's
    last safe point."""
    from probvis.interrupts import check_stop, reset_stop

    reset_stop()
    try:
        with deferred_interrupts():
            os.kill(os.getpid(), signal.SIGTERM)
    except KeyboardInterrupt:
        pass  # a library's `except BaseException`
    with pytest.raises(KeyboardInterrupt):
        check_stop()
    reset_stop()
    check_stop()


def test_a_stop_as_a_study_finishes_says_its_report_is_complete(monkeypatch, tmp_path, capsys):
    """A stop that arrived while the report was written (deferred, then swallowed) still ends the command with
    130, but the report is whole: the message says so, not "run the same command to resume"."""
    import probvis.experiments
    from probvis.cli import main

    def finished_study(exp, out, *args):
        try:
            with deferred_interrupts():
                os.kill(os.getpid(), signal.SIGTERM)
        except KeyboardInterrupt:
            pass  # swallowed, as `experiment` swallows one that arrives while its report is written
        return None, out / "index.html", None

    monkeypatch.setattr(probvis.experiments, "experiment", finished_study)
    assert main(["experiment", "--quick", "-o", str(tmp_path / "rep")]) == 130
    err = capsys.readouterr().err
    assert f"interrupted as the study finished; its report is complete: {tmp_path / 'rep' / 'index.html'}" in err
    assert "resume" not in err
