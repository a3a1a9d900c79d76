"""Output folders and files get the permissions the umask gives (not tempfile's 0700 / 0600)."""

import os
import stat
import subprocess
import sys


def test_outputs_honour_the_umask(tmp_path, frames_dir):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"preset: geometry\ninput: {{path: {frames_dir}, scale: 1.0}}\n"
                    "stages: {trajectories: null, rigidity: null}\n"
                    f"output: {{dir: {tmp_path / 'out'}, save: [flow, panels]}}\ncache: {{enabled: false}}\n")
    result = subprocess.run([sys.executable, "-m", "eponet.run", str(spec), "-q"], capture_output=True, text=True,
                            timeout=300, preexec_fn=lambda: os.umask(0o022))
    assert result.returncode == 0, result.stderr
    modes = {p.relative_to(tmp_path).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "out").rglob("*")}
    assert modes["out/clip"] == 0o755 and modes["out/run.json"] == 0o644
    assert {m for p, m in modes.items() if (tmp_path / p).is_dir()} == {0o755}
    assert {m for p, m in modes.items() if (tmp_path / p).is_file()} == {0o644}
