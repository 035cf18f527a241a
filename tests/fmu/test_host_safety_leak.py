"""Instantiate/free cycles of a pythonfmu FMU in one host process leave nothing of ours behind:
one slave class, one copy of the resources folder in sys.path, and the memory that remains per
cycle is pythonfmu's own (its C++ layer keeps about 2.5 KB per fmi2Instantiate, not ours to
free).

The RSS is read in pages (4096 B), so over CYCLES = 500 cycles it resolves 8 B per cycle: far
below the margin between the bound (4096 B per cycle) and pythonfmu's 2.5 KB, so the bound
means what it meant over 1500 cycles: a leak of ours of more than the ~1.5 KB per cycle between
pythonfmu's share and the bound (a slave object with its arrays, say) still crosses it."""

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
PYTHONFMU_PER_CYCLE = 4096
"""Bytes per cycle allowed: pythonfmu's C++ layer alone keeps about 2.5 KB."""

CHILD = """
import gc, json, sys
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
classes = [c for c in gc.get_objects()
           if isinstance(c, type) and c.__name__ == description.coSimulation.modelIdentifier]
print(json.dumps({"per_cycle": (rss() - before) / cycles, "classes": len(classes),
                  "resources_in_path": max(sys.path.count(p) for p in sys.path)}))
"""


@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_instantiate_free_cycles_keep_nothing_of_ours(paper_design_fmus, kind):
    done = subprocess.run([sys.executable, "-c", CHILD, str(paper_design_fmus[kind]), str(WARM_UP),
                           str(CYCLES)], capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["classes"] == 1
    assert result["resources_in_path"] == 1
    assert result["per_cycle"] < PYTHONFMU_PER_CYCLE, result
