"""Progress reporting: a tqdm bar on a terminal, a plain line every few seconds otherwise."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, end_time: float, enabled: bool = True, every_s: float = 5.0, stream=None):
        self.end_time = end_time
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.every_s = every_s
        self.bar = None
        self.t0 = time.perf_counter()
        self.last = self.t0
        self.step0 = 0
        if enabled and self.stream.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=end_time, unit="s(sim)", file=self.stream, dynamic_ncols=True,
                            bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s sim [{elapsed}<{remaining}{postfix}]")

    def note(self, text: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.write(text)
        else:
            print(text, file=self.stream, flush=True)

    def reset_clock(self, step: int) -> None:
        """Start the steps/s count after the first (compiling) step."""
        self.t0 = time.perf_counter()
        self.step0 = step

    def update(self, sim_time: float, step: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        rate = (step - self.step0) / max(now - self.t0, 1e-9)
        if self.bar is not None:
            self.bar.n = min(sim_time, self.end_time)
            self.bar.set_postfix_str(f"step {step}, {rate:.0f} steps/s", refresh=False)
            self.bar.refresh()
        elif now - self.last >= self.every_s:
            self.last = now
            frac = min(sim_time / self.end_time, 1.0) if self.end_time else 1.0   # the last step may pass the end
            eta = (now - self.t0) * (1 - frac) / frac if frac > 0 else float("nan")
            print(f"t = {sim_time:.4f}/{self.end_time:.4f} s  step {step}  {rate:.0f} steps/s  "
                  f"ETA {eta:.0f} s", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
