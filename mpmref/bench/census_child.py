"""The child process of the compile census (:mod:`mpmref.bench.compile_census`): one first run, its compilations.

Run as a script, ``python census_child.py SCENE STEPS OUT``, with the checkout to measure first on the import path and
an empty Numba cache: it runs ``mpmref run SCENE --steps STEPS --backend numba`` in this process, records every
compilation Numba's event API reports (``numba:compile``) with the process's CPU clock, and prints one JSON document:
``{"status", "cpu_s", "compiles"}``, ``compiles`` a list of ``[label, dispatcher id, cpu_s]`` per compilation, its
own CPU seconds (those of the compilations nested in it, a callee's, left out, so that the seconds add up). It imports
nothing of the package but the command line, so it measures an older checkout as well as this one.
"""

import json
import resource
import sys
import time

from numba.core import event


class CompileRecorder(event.Listener):
    """The ``numba:compile`` events of a process, each with the process's CPU time when it came."""

    def __init__(self):
        self.events = []

    def on_start(self, ev):
        self.events.append((time.process_time(), True, ev.data["dispatcher"]))

    def on_end(self, ev):
        self.events.append((time.process_time(), False, ev.data["dispatcher"]))


def label(dispatcher):
    """``module.qualname`` of a dispatcher's Python function, the module's last part only."""
    function = dispatcher.py_func
    return f"{function.__module__.rsplit('.', 1)[-1]}.{function.__qualname__}"


def own_times(events):
    """``[label, dispatcher id, own CPU seconds]`` per compilation of ``events`` (``(cpu, is_start, dispatcher)`` in
    order; a compilation's nested ones are subtracted from it)."""
    compiles, stack = [], []
    for cpu, is_start, dispatcher in events:
        if is_start:
            stack.append([cpu, 0.0])
            continue
        start, nested = stack.pop()
        compiles.append([label(dispatcher), id(dispatcher), cpu - start - nested])
        if stack:
            stack[-1][1] += cpu - start
    return compiles


def main(argv):
    """Run the scene ``argv[0]`` for ``argv[1]`` steps on the Numba backend, writing to ``argv[2]``; print the JSON."""
    from mpmref.cli import main as cli

    scene, steps, out = argv
    recorder = CompileRecorder()
    with event.install_listener("numba:compile", recorder):
        status = cli(["run", scene, "--steps", steps, "--backend", "numba", "--out", out, "--no-progress"])
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"status": status, "cpu_s": usage.ru_utime + usage.ru_stime,
                      "compiles": own_times(recorder.events)}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
