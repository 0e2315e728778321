"""`mros topic pub -f`: reading YAML documents, and the usage and input errors that stop it before publishing."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from mros_cli.main import cli
from mros_cli.topic import file_documents

from mrosd.errors import MrosError


def test_a_file_yields_one_value_per_yaml_document_skipping_empty_ones(tmp_path: Path) -> None:
    doc = tmp_path / "m.yaml"
    doc.write_text("data: a\n---\n---\ndata: b\n")
    assert file_documents(str(doc)) == [{"data": "a"}, {"data": "b"}]


def test_a_missing_file_or_invalid_yaml_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(MrosError, match="cannot read"):
        file_documents(str(tmp_path / "absent.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("data: [unclosed\n")
    with pytest.raises(MrosError, match="invalid YAML"):
        file_documents(str(bad))


def test_values_and_a_file_together_are_a_usage_error(tmp_path: Path) -> None:
    doc = tmp_path / "m.yaml"
    doc.write_text("data: a\n")
    result = CliRunner().invoke(cli, ["topic", "pub", "/t", "std_msgs/String", "hi", "-f", str(doc)])
    assert result.exit_code == 2


def test_a_wrong_field_in_a_file_exits_1_naming_it_without_contacting_a_master(tmp_path: Path) -> None:
    doc = tmp_path / "m.yaml"
    doc.write_text("data: a\n---\n{data: b, bogus: 1}\n")
    result = CliRunner().invoke(
        cli, ["--master-uri", "http://127.0.0.1:9/", "topic", "pub", "/t", "std_msgs/String", "-f", str(doc)]
    )
    assert result.exit_code == 1
    assert "bogus" in result.output
