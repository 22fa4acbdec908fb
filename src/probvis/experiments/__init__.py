"""`probvis experiment`: a study of scenes x methods x shadow-ray counts x seeds, run on Dask, cached on disk,
reported as a browsable folder (see `config`, `runner`, `results`, `report`)."""
import os
import warnings
from pathlib import Path

from ..errors import ProbvisError, checked_call, is_path
from ..interrupts import deferred_interrupts
from ..io.atomic import exclusive_folder
from .config import (Experiment, MethodSpec, SceneSpec, load_experiment, parse_experiment, quick_experiment,
                     recheck, reference_noise_problem)
from .report import report_folders, report_problem, write_report
from .results import measure
from .runner import check_run_options, load_scenes, run_experiment


@checked_call
def experiment(exp, out, cache=None, workers=1, scheduler=None, progress=True, command="", log=None):
    """Run `exp` (an `Experiment` or a TOML path), cache its renders and write the report to folder `out`.

    Returns (results, path of index.html, run summary)."""
    if not (isinstance(exp, Experiment) or is_path(exp)):
        raise ProbvisError(f"exp must be an Experiment (parse_experiment builds one from a dict) or an experiment "
                           f"file's path, got {type(exp).__name__}")
    exp = recheck(exp) if isinstance(exp, Experiment) else load_experiment(exp)
    if not isinstance(command, str):
        raise ProbvisError(f"command must be the command line shown in the report (a string), got {command!r}")
    if not is_path(out):
        raise ProbvisError(f"out must be the report's folder (a path), got {type(out).__name__}")
    if cache is not None and not is_path(cache):
        raise ProbvisError(f"cache must be a folder (a path) or None, got {type(cache).__name__}")
    out, cache = os.fspath(out), None if cache is None else os.fspath(cache)
    for name, folder in (("out", out), ("cache", cache)):
        if folder is not None and not str(folder).strip():
            raise ProbvisError(f"{name} must name a folder, got an empty name")
    check_run_options(workers, scheduler, progress, log)
    workers = int(workers)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ProbvisError(f"report folder '{out}' is a file: give -o a folder (new or existing)")
    above = next((p for p in out.parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise ProbvisError(f"report folder '{out}' cannot be made: '{above}' is a file: give -o a folder (new or "
                           "existing)")
    if (noisy := reference_noise_problem(exp)) is not None:
        warnings.warn(noisy, stacklevel=2)
    scenes = load_scenes(exp)
    if (problem := report_problem(exp, out, {name: scene.inputs for name, scene in scenes.items()})) is not None:
        raise ProbvisError(problem)
    with exclusive_folder(out, "report folder", report_folders(exp)):
        run = run_experiment(exp, Path(cache) if cache else out / "cache", workers, scheduler, progress, log, scenes)
        results = measure(exp, run)
        index = None
        try:
            with deferred_interrupts():  # seconds: an interrupt waits for a whole report, not half of one
                index = write_report(exp, run, results, out, command)
        except KeyboardInterrupt:
            if index is None:
                raise
            # the stop arrived while the report was written: the study is complete, nothing is left to stop
    return results, index, run


__all__ = ["Experiment", "MethodSpec", "SceneSpec", "experiment", "load_experiment", "measure", "parse_experiment",
           "quick_experiment", "run_experiment", "write_report"]
