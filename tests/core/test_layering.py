"""The engine's headers are layered (docs/architecture.md): core/ is the bottom layer and
includes nothing above it (only core/ headers and the standard or CUDA headers), and the
spatial layer does not reach up into physics, scenes or sim."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "cpp" / "include" / "corpuscle"
INCLUDE = re.compile(r'^\s*#\s*include\s+"corpuscle/([a-z_]+)/', re.M)


def includes(layer):
    out = []
    for h in sorted((ROOT / layer).glob("*.h")):
        out += [(h.name, m.group(1)) for m in INCLUDE.finditer(h.read_text())]
    return out


def test_core_includes_nothing_above_it():
    assert (ROOT / "core" / "lanes.h").exists()
    above = [(h, dep) for h, dep in includes("core") if dep != "core"]
    assert above == [], above


def test_spatial_includes_only_core_and_spatial():
    found = includes("spatial")
    assert any(dep == "core" for _, dep in found)
    above = [(h, dep) for h, dep in found if dep not in ("core", "spatial")]
    assert above == [], above


def test_physics_and_dem_do_not_reach_into_the_engine_or_scenes():
    # physics: formulas on plain values
    above = [(h, dep) for h, dep in includes("physics") if dep not in ("core", "physics")]
    assert above == [], above
    # dem: the soft-sphere stages every DEM kind shares; of sim/ only the parameter reader and
    # the clock (its field rows and pointers come from core/field_ptrs.h)
    pattern = re.compile(r'^\s*#\s*include\s+"corpuscle/(sim/[a-z_]+\.h|scenes/)', re.M)
    reached = sorted({m.group(1) for h in (ROOT / "dem").glob("*.h") for m in pattern.finditer(h.read_text())})
    assert set(reached) <= {"sim/params.h", "sim/table.h"}, reached
