"""The gateway route to a proxy: a study served here (services/study/runner.py), headless stand-in
participants (services/study/standin.py) playing a library bait through the page's WebSocket
protocol in real time, their recordings and sidecars as the study leaves them, and a proxy trained
on them (`tsf proxy train`'s core). Prints the wall time per trial, the trials done, and the
proxy's split and held-out log-likelihood; the stand-in plays policy keys, not human-like hands
(bench/proxies.py measures those, recorded in-process: docs/proxies.md says why).

    nice .venv/bin/python bench/proxies_gateway.py [--participants 3] [--trials 2] [--seconds 10]
        [--policy B5] [--out bench-proxies-gateway]
"""

from __future__ import annotations

import argparse
import asyncio
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from services.human.gateway import Web
from services.proxy.train import Settings, train
from services.study.core import StudyConfig, Variant
from services.study.runner import run_study
from services.study.serving import Serving
from services.study.standin import stand_in

TOKEN = "bench"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--participants", type=int, default=3)
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of a trial")
    parser.add_argument("--policy", default="B5", help="the stand-ins' bait")
    parser.add_argument("--max-matches", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("bench-proxies-gateway"))
    args = parser.parse_args()
    config = StudyConfig(
        "proxies", (Variant.read("S5", bait="B1", shooter="S5"),), args.trials, args.seconds, 1, ("bait",)
    )
    study_dir = args.out / "study"
    stop, urls = threading.Event(), []
    started = time.monotonic()
    with ThreadPoolExecutor(1) as pool:
        serving = Serving(max_matches=args.max_matches, test_token=TOKEN)
        server = pool.submit(
            run_study, config, study_dir, Web(port=0), stop, lambda g: urls.append(g.url), serving
        )
        while not urls:
            if server.done():
                server.result()
            time.sleep(0.05)

        async def crowd() -> list:
            policies = {"bait": args.policy, "shooter": "S5"}
            return await asyncio.gather(
                *(stand_in(urls[0], policies, seed=i, test=TOKEN) for i in range(args.participants))
            )

        try:
            reports = asyncio.run(crowd())
        finally:
            stop.set()
        study = server.result()
    wall = time.monotonic() - started
    attempts = [a for p in study.participants.values() for a in p.attempts]
    done = [a for a in attempts if a["status"] == "done"]
    print(
        f"{len(done)} of {len(attempts)} attempts done, {sum(r.done for r in reports)} of "
        f"{args.participants} stand-ins finished, in {wall:.0f} s: {wall / max(len(done), 1):.1f} s of wall "
        f"time per {args.seconds:.0f}-second trial ({args.max_matches} matches at once)"
    )
    paths = sorted((study_dir / "recordings").glob("*.tsflog"))
    record = train(paths, "bait", args.out / "proxy", Settings(), 1 / args.participants)
    metrics = record["metrics"]
    print(
        f"proxy of {args.policy} from {len(record['recordings'])} recordings ({len(record['excluded'])} "
        f"exclusions named): trained on {record['split']['train']}, held out {record['split']['held_out']}; "
        f"held-out log-likelihood {metrics['held_out_loglik']:.3f} nats/frame "
        f"at epoch {metrics['best_epoch']}"
    )


if __name__ == "__main__":
    main()
