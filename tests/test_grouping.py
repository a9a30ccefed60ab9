"""How `make test` hands tests to its worker processes (tests/conftest.py): the tests that share a module fixture are
one group, and pytest-xdist's `--dist loadgroup` sees it (a group's tests go to one worker, which builds the fixture
once)."""

import pytest


@pytest.fixture(scope="module")
def shared() -> object:
    return object()


def test_a_test_of_a_module_fixture_is_in_its_modules_group_and_the_workers_see_it(request, shared):
    group = request.node.path.relative_to(request.config.rootpath).as_posix()
    assert [mark.args for mark in request.node.iter_markers("xdist_group")] == [(group,)]
    if getattr(request.config.option, "loadgroup", False):  # a worker of `pytest -n N --dist loadgroup`
        assert request.node.nodeid.endswith(f"@{group}"), (
            "pytest-xdist cannot see the group (pyproject.toml: pytest below 9.2)"
        )


def test_a_test_of_no_module_fixture_is_in_no_group(request):
    assert not list(request.node.iter_markers("xdist_group"))
