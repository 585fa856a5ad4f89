"""``strauss-fit study`` end to end: the report's files, the verdicts printed, and a second
run into the same folder refused without --force."""

import json

from strauss_fit_cli.main import main


def test_study_command_writes_the_report_and_refuses_to_overwrite_it(tmp_path, capsys):
    outdir = tmp_path / "report"
    assert main(["study", "--size", "tiny", "-o", str(outdir), "--quiet"]) == 0
    out = capsys.readouterr().out
    study = json.loads((outdir / "study.json").read_text())
    assert study["config"]["name"] == "tiny" and len(study["conclusions"]) == 4
    for verdict in study["conclusions"]:
        assert verdict["key"] in out
    assert "study.html" in out and (outdir / "study.md").is_file()
    # a second run into the same folder is refused without --force
    code = main(["study", "--size", "tiny", "-o", str(outdir), "--quiet"])
    assert code == 2 and "pass --force" in capsys.readouterr().err
