"""The real datasets are the files DATASETS.md names: every checksum of scripts/datasets.sha256."""

import hashlib


def test_every_dataset_file_has_its_checksum(datasets, repo):
    lines = (repo / "scripts" / "datasets.sha256").read_text().splitlines()
    assert len(lines) >= 20
    for line in lines:
        expected, name = line.split(maxsplit=1)
        path = datasets / name
        assert path.is_file(), f"{path} is missing (DATASETS.md)"
        assert hashlib.sha256(path.read_bytes()).hexdigest() == expected, f"{path} differs"
