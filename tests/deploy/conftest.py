"""Fixtures for deployment tests: network-namespace labs (fail loudly when unavailable)."""

import pytest

from contactflow.deploy.netns import NetLab, NetnsUnavailable


def make_lab(hosts):
    lab = NetLab(hosts)
    try:
        lab.open()
    except NetnsUnavailable as exc:
        pytest.fail(f"multi-host tests need network namespaces: {exc}", pytrace=False)
    return lab


@pytest.fixture(scope="module")
def lab_factory():
    labs = []

    def factory(hosts):
        lab = make_lab(hosts)
        labs.append(lab)
        return lab

    yield factory
    for lab in labs:
        lab.close()
