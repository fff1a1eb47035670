"""Print the dependencies (and chosen extras) of a pyproject.toml, one per line, for pip."""

from __future__ import annotations

import sys
import tomllib


def main() -> None:
    path, *extras = sys.argv[1:]
    with open(path, "rb") as f:
        project = tomllib.load(f)["project"]
    deps = list(project.get("dependencies", []))
    for extra in extras:
        deps += project.get("optional-dependencies", {}).get(extra, [])
    print("\n".join(deps))


if __name__ == "__main__":
    main()
