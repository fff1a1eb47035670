"""How the docs test finds examples and their directives (ether_ros.testing.docs)."""

from __future__ import annotations

from pathlib import Path

from ether_ros.testing.docs import blocks, doc_files, substitute

PAGE = """\
# A page

```sh
ether-ros slaves -i eth1
```

<!-- not-run: needs a real NIC -->
```bash
ether-ros rt setup -i enp5s0 --cpu 3 --apply
```

<!-- docs-test: sim=config/arm6.yaml -->

```python
print("arm")
```

<!-- docs-test: continues -->
```python
print("more")
```

```yaml
bus: {cycle_us: 400}
```

````md
```sh
not an example: inside a longer fence
```
````
"""


def test_examples_directives_and_languages(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    found = blocks(page)
    assert [(b.line, b.lang) for b in found] == [
        (3, "sh"),
        (8, "sh"),
        (14, "python"),
        (19, "python"),
    ]
    assert found[0].not_run is None and found[0].text == "ether-ros slaves -i eth1\n"
    assert found[1].not_run == "needs a real NIC"
    assert found[2].options == {"sim": "config/arm6.yaml"}
    assert found[3].options == {"continues": ""}
    assert "page.md:3" in found[0].where


def test_interfaces_are_substituted_by_role() -> None:
    text = (
        "ether-ros sim x.yaml -i ecat0s &\nether-ros slaves -i ecat0\n"
        "Bus.open(c, interface='veth0')"
    )
    out = substitute(text, master="m0", sim="s0")
    assert (
        out == "ether-ros sim x.yaml -i s0 &\nether-ros slaves -i m0\nBus.open(c, interface='m0')"
    )
    assert substitute("eth10 veth01", "m0", "s0") == "eth10 veth01"  # whole names only


def test_the_repository_docs_are_found() -> None:
    repo = Path(__file__).resolve().parents[2]
    files = doc_files(repo)
    assert files[0].name == "README.md" and any(f.name == "user-guide.md" for f in files)
    examples = [b for f in files for b in blocks(f)]
    assert any(b.lang == "python" for b in examples) and any(b.lang == "sh" for b in examples)
    for b in examples:
        assert b.not_run is None or len(b.not_run) >= 8, f"{b.where}: say why it cannot run"


def test_the_docs_rt_cpu_becomes_one_this_host_has() -> None:
    assert substitute("rt check -i eth1 --cpu 3", "m0", "s0", cpu=1) == "rt check -i m0 --cpu 1"
    assert substitute("--cpu 31", "m0", "s0", cpu=1) == "--cpu 31"
