"""The CUDA build takes every architecture list the README shows, and picks the documented
default when no GPU is visible. CMake configures the project in a scratch folder and
compiles the one host file that carries the architecture list (the list once reached that
compile command with its ';', which the shell took as the end of the command)."""
import importlib.util
import os
import pathlib
import shutil
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
needs = [shutil.which("nvcc"), shutil.which("cmake"), importlib.util.find_spec("nanobind")]
pytestmark = pytest.mark.skipif(not all(needs) or not (REPO / "CMakeLists.txt").exists(),
                                reason="needs nvcc, cmake, nanobind and the source tree")


def configure(tmp_path, *defines):
    env = {k: v for k, v in os.environ.items() if not k.startswith("CORPUSCLE_")}
    build = tmp_path / "build"
    p = subprocess.run(["cmake", "-S", str(REPO), "-B", str(build), "-DCORPUSCLE_CUDA=ON",
                        "-DCMAKE_BUILD_TYPE=Release", f"-DPython_EXECUTABLE={sys.executable}", *defines],
                       capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    return build, p.stdout


@pytest.mark.parametrize("archs", ["80;90", "80,90"])
def test_an_architecture_list_compiles(tmp_path, archs):
    build, out = configure(tmp_path, f"-DCORPUSCLE_CUDA_ARCHITECTURES={archs}")
    assert "corpuscle: CUDA backend ON, architectures 80;90" in out
    p = subprocess.run(["cmake", "--build", str(build), "--target", "cpp/bindings/info_bindings.cpp.o"],
                       capture_output=True, text=True, timeout=600)
    if p.returncode != 0 and "No rule to make target" in (p.stdout + p.stderr):
        # a generator without per-object targets: build the object through the make program
        p = subprocess.run(["make", "-C", str(build), "cpp/bindings/info_bindings.cpp.o"],
                           capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    flags = (build / "CMakeFiles" / "_core.dir" / "flags.make").read_text()
    assert 'CPS_CUDA_ARCHS=\\"80,90\\"' in flags


@pytest.mark.skipif(shutil.which("nvidia-smi") is not None, reason="a GPU may be visible here")
def test_without_a_visible_gpu_the_default_is_turing_and_ampere_plus_ptx(tmp_path):
    _, out = configure(tmp_path)
    assert "corpuscle: CUDA backend ON, architectures 75-real;80" in out
