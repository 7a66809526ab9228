"""The marks lamp-patrol's tests use, known also where `rapp test` runs them without the checkout's
configuration: `slow` (the full house: minutes; `-m "not slow"` leaves them out) and `timeout`
(pytest-timeout's limit, where that plugin is installed)."""


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: the full house, minutes per robot")
    config.addinivalue_line("markers", "timeout(seconds): pytest-timeout's limit, where it is installed")
