# shared pytest configuration for corpuscle's tests (keep each addition small and self-contained)


def pytest_configure(config):
    # a corpuscle warning escaping a test fails it; a test that expects one uses pytest.warns
    config.addinivalue_line("filterwarnings", "error::corpuscle.io.TruncatedRunWarning")
