"""Instantiate/free cycles of a pythonfmu FMU in one host process leave nothing of ours behind:
one slave class, one copy of the resources folder in sys.path, no slave object alive, and the
Python memory that remains per cycle is pythonfmu's own (its C++ layer keeps 2.2-2.6 KB of
Python objects per fmi2Instantiate, not ours to free; measured with tracemalloc, all of it
allocated under fmpy's fmi2Instantiate call, the same before and after changes to the slaves).

Two measures, each over CYCLES = 500 cycles after WARM_UP: the process's RSS, read in pages,
then the Python memory retained (tracemalloc, every domain, numpy's array data included),
bounded by PYTHONFMU_PER_CYCLE, which a leaked slave object with its arrays crosses; the RSS
is bounded coarsely by RSS_PER_CYCLE (the allocator's fragmentation moves it by a few hundred
bytes per cycle when the slave's allocation pattern changes, with no object retained; a
pythonfmu FMU without the slaves' guard against pythonfmu re-running its script keeps a class
and 36 KB of Python objects per cycle and crosses both)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                       reason="RSS from /proc, the status wrapper as on linux64"),
]

WARM_UP, CYCLES = 300, 500
PYTHONFMU_PER_CYCLE = 3072
"""Python bytes retained per cycle allowed: pythonfmu's C++ layer alone keeps 2.2-2.6 KB."""
RSS_PER_CYCLE = 8192
"""Resident bytes per cycle allowed (coarse: a leaked slave with its arrays, or a class per
cycle, is tens of KB)."""

CHILD = """
import gc, json, sys, tracemalloc
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

path, warm_up, cycles = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
description = read_model_description(path)
fmu = FMU2Slave(guid=description.guid, unzipDirectory=extract(path), instanceName="cycled",
                modelIdentifier=description.coSimulation.modelIdentifier)

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096

def cycle():
    fmu.instantiate()
    fmu.freeInstance()

for _ in range(warm_up):
    cycle()
gc.collect()
before = rss()
for _ in range(cycles):
    cycle()
gc.collect()
after = rss()
tracemalloc.start(1)  # after the RSS: its own records would count there
python_before = tracemalloc.take_snapshot()
for _ in range(cycles):
    cycle()
gc.collect()
python_after = tracemalloc.take_snapshot()
retained = sum(s.size_diff for s in python_after.compare_to(python_before, "filename"))
slaves = sum(1 for o in gc.get_objects()
             if type(o).__name__ == description.coSimulation.modelIdentifier)
classes = [c for c in gc.get_objects()
           if isinstance(c, type) and c.__name__ == description.coSimulation.modelIdentifier]
print(json.dumps({"per_cycle": (after - before) / cycles, "python_per_cycle": retained / cycles,
                  "slaves": slaves, "classes": len(classes),
                  "resources_in_path": max(sys.path.count(p) for p in sys.path)}))
"""


@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_instantiate_free_cycles_keep_nothing_of_ours(paper_design_fmus, kind):
    done = subprocess.run([sys.executable, "-c", CHILD, str(paper_design_fmus[kind]), str(WARM_UP),
                           str(CYCLES)], capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["classes"] == 1 and result["slaves"] == 0, result
    assert result["resources_in_path"] == 1
    assert result["python_per_cycle"] < PYTHONFMU_PER_CYCLE, result
    assert result["per_cycle"] < RSS_PER_CYCLE, result


@pytest.mark.parametrize("block", [("sine", (2,)), ("gain", (2, 3))])
def test_harness_blocks_keep_nothing_either(block, tmp_path):
    """The harness's own pythonfmu blocks are guarded the same way (fhobs.build.slave_script):
    without the guard a block kept a class and 36 KB per cycle."""
    from harness.blocks import block_fmu

    fmu = block_fmu(*block, tmp_path)
    done = subprocess.run([sys.executable, "-c", CHILD, str(fmu), str(WARM_UP), str(CYCLES)],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["classes"] == 1 and result["slaves"] == 0, result
    assert result["resources_in_path"] == 1
    assert result["python_per_cycle"] < PYTHONFMU_PER_CYCLE, result
    assert result["per_cycle"] < RSS_PER_CYCLE, result
