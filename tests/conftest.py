# shared pytest configuration for corpuscle's tests (keep each addition small and self-contained).
# The tests are grouped as the sources are (core/, sim/, spatial/, physics/, scenes/<kind>/, cli/,
# io/, viz/, live/); helpers shared across groups (cli_script.py, viz_runs.py) sit here, in the
# folder pytest puts on sys.path for this file.
import pytest


def pytest_configure(config):
    # a corpuscle warning escaping a test fails it; a test that expects one uses pytest.warns
    config.addinivalue_line("filterwarnings", "error::corpuscle.io.TruncatedRunWarning")


@pytest.fixture(params=["serial", "cpu", pytest.param("cuda", marks=pytest.mark.gpu)])
def backend(request):
    """Every backend in turn: serial, cpu (OpenMP) and cuda (``gpu``-marked, skipped where no
    CUDA backend is usable). A test that takes ``backend`` runs once for each."""
    if request.param == "cuda":
        from corpuscle.simulation import cuda_status

        ok, why = cuda_status()
        if not ok:
            pytest.skip(f"no usable CUDA backend: {why}")
    return request.param
