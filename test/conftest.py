"""Helpers shared by the system tests."""

import os
import subprocess


def run_at_once(cmds, timeout):
    """Start every command of ``cmds`` at once and wait for all: (returncode, stdout, stderr)
    of each, in order; those still running after ``timeout`` s each are killed (and the
    TimeoutExpired raised)."""
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in cmds]
    try:
        outs = [p.communicate(timeout=timeout) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return [(p.returncode, stdout, stderr) for p, (stdout, stderr) in zip(procs, outs)]


def short_scenario(folder, base="rtk", name="short_rtk", laps=1, max_duration=30.0) -> str:
    """Scenario ``base`` cut to ``max_duration`` s of ``laps`` laps of the figure eight,
    ending on its duration (a run's plumbing, not its figures); returns the YAML's path."""
    import yaml
    from quadrivio.scenario import resolve

    with open(resolve(base)) as f:
        data = yaml.safe_load(f)
    data["name"] = name
    data["path"] = {"figure_eight": {"laps": laps}}
    data["run"] = dict(data.get("run", {}), max_duration=max_duration, end="duration")
    path = os.path.join(str(folder), f"{name}.yaml")
    with open(path, "w") as f:
        yaml.safe_dump(data, f)
    return path
