"""The package, its help texts and its docs stand alone: they cite no section of a
specification and no issue number that a user of the repository cannot read."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLACES = ('sapga_ros', 'sim_nodes', 'docs', 'msg_configs', 'README.md')
CITATION = re.compile(r'\bSPEC\b|\bissues? #?\d')


def test_no_spec_or_issue_references_in_the_package_or_its_docs():
    found = []
    for place in PLACES:
        path = ROOT / place
        for f in [path] if path.is_file() else sorted(path.rglob('*')):
            if f.is_file() and f.suffix in ('.py', '.md', '.yaml', '.json', '.txt', ''):
                for k, line in enumerate(f.read_text(errors='replace').splitlines(), 1):
                    if CITATION.search(line):
                        found.append(f'{f.relative_to(ROOT)}:{k}: {line.strip()[:80]}')
    assert not found, '\n'.join(found)
