"""Provenance of a run: the code version a result header names."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from scaletwin_envs.host import REVISION_ENV, git_revision


def test_revision_of_this_checkout_is_its_head(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(REVISION_ENV, raising=False)
    head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=Path(__file__).parent, text=True,
                          capture_output=True, check=False)
    if head.returncode != 0:
        pytest.skip("the tests run from a tree without git")
    assert git_revision().split("+")[0] == head.stdout.strip()


def test_a_copy_without_git_reports_the_named_commit_and_says_so(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path.parent))  # git must not find a repository above
    monkeypatch.delenv(REVISION_ENV, raising=False)
    assert git_revision(tmp_path) == "unknown"
    monkeypatch.setenv(REVISION_ENV, "abc123def456")
    rev = git_revision(tmp_path)
    assert rev.startswith("abc123def456 ") and REVISION_ENV in rev


def test_a_named_commit_other_than_gits_comes_first_with_gits_beside_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """A tree sent to another machine with an older repository: the commit the sender names is the code's, git's
    answer is kept beside it; naming git's own commit changes nothing."""
    monkeypatch.delenv(REVISION_ENV, raising=False)
    found = git_revision()
    if found == "unknown" or "(" in found:
        pytest.skip("the tests run from a tree without git")
    monkeypatch.setenv(REVISION_ENV, "0123456789ab")
    assert git_revision() == f"0123456789ab (named by {REVISION_ENV}; git here: {found})"
    monkeypatch.setenv(REVISION_ENV, found.split("+")[0][:7])
    assert git_revision() == found
