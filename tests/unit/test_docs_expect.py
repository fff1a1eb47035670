"""The docs test's ``<!-- docs-expect: REGEX -->``: an example's claim (its printed result code)
is checked, not only its exit code (issue 24, item 6)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ether_ros.testing.docs import blocks

PAGE = """\
<!-- docs-test: sim=config/arm6.yaml node -->
<!-- docs-expect: ^4 0 SUCCESSFUL elbow=0\\.(29|30|31) -->
```python
print(4, 0, "SUCCESSFUL", "elbow=0.30")
```

```python
print("no claim")
```
"""


def test_the_expectation_is_read_with_the_other_directives(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    first, second = blocks(page)
    assert first.options == {"sim": "config/arm6.yaml", "node": ""}
    assert first.expect == r"^4 0 SUCCESSFUL elbow=0\.(29|30|31)"
    assert second.expect is None
    # What the docs test matches: the success line passes, an aborted goal's does not.
    assert re.search(first.expect, "4 0 SUCCESSFUL elbow=0.30\n", re.M)
    assert not re.search(first.expect, "6 -4 SUCCESSFUL elbow=0.02\n", re.M)


def test_a_bad_expectation_fails_when_the_page_is_read(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("<!-- docs-expect: ^(4 -->\n```python\nprint(4)\n```\n")
    with pytest.raises(re.error):
        blocks(page)


def test_the_shipped_fjt_example_claims_success() -> None:
    """docs/ros.md's FollowJointTrajectory example takes the lease, enables the axes and is
    checked for its result code (the docs test runs it on the simulated arm6)."""
    ros = Path(__file__).resolve().parents[2] / "docs" / "ros.md"
    (fjt,) = [b for b in blocks(ros) if "TrajectoryActionClient(c.node" in b.text]
    assert fjt.options.get("sim") == "config/arm6.yaml" and "node" in fjt.options
    assert fjt.expect is not None and fjt.expect.startswith("^4 0 ")
    assert "acquire_lease()" in fjt.text and 'axis_command("enable")' in fjt.text
