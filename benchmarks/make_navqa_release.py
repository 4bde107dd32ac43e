"""Write a small NaVQA folder laid out file for file as the ReMEmbR release ships it (the test
fixture `tests/eval/release_files.py`: remembr/data/navqa/{data.csv in UTC-8, 0/qa_unfilled.json}
and remembr/coda_data/0/<pose_ts>.pkl, 60 coloured frames, 7 questions, one of them an
annotation slip outside its clip), for measured runs of `ravenmem eval` on the NaVQA layout.

    python benchmarks/make_navqa_release.py /tmp/navqa-remembr
    ravenmem eval --dataset navqa:/tmp/navqa-remembr/remembr ...
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from tests.eval.release_files import write_remembr_release  # noqa: E402


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: make_navqa_release.py FOLDER")
    pkg = write_remembr_release(Path(sys.argv[1]))
    print(f"wrote the ReMEmbR NaVQA layout: navqa:{pkg}")


if __name__ == "__main__":
    main()
