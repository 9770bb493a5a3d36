"""Progress bars (tqdm) for the driver's loops: a study's runs, a sweep's points, the
adaptation steps of one run.

A bar is drawn on stderr only when stderr is a terminal (tqdm's disable=None); in a
log, a pipe or under pytest the callers keep their plain lines instead. tqdm is
imported when the first bar is made: `python -m driver run` on a scene without
adaptation never imports it.
"""

import contextlib
import sys

_study = {"bar": None, "started": 0}


def on_terminal():
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def bar(total=None, desc=None, unit="run", initial=0):
    """A tqdm bar on stderr, or None when stderr is not a terminal (tqdm's own
    disable=None test, made here so that callers know to print plain lines)."""
    if not on_terminal():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, initial=initial, file=sys.stderr, dynamic_ncols=True,
                leave=False)


def write(line):
    """A line on stderr that does not break a bar being drawn."""
    if on_terminal() and "tqdm" in sys.modules:
        sys.modules["tqdm"].tqdm.write(line, file=sys.stderr)
    else:
        print(line, file=sys.stderr, flush=True)


@contextlib.contextmanager
def study_bar(name):
    """One bar per study over its runs (their number is not known in advance):
    run_started moves it on."""
    _study.update(bar=bar(desc=f"study {name}"), started=0)
    try:
        yield
    finally:
        study = _study["bar"]
        if study is not None:
            if _study["started"]:
                study.update(1)
            study.close()
        _study.update(bar=None, started=0)


def run_started(text):
    """A study's next run starts (the previous one, if any, is done). False when no bar
    shows it (no study bar, or stderr is not a terminal): the caller prints a line."""
    study = _study["bar"]
    if study is None:
        return False
    if _study["started"]:
        study.update(1)
    _study["started"] += 1
    study.set_postfix_str(text, refresh=True)
    return True
