"""The `tdc` law (docs/controllers.md; controller/law/src/law.rs) as a deltaloop controller
process in Python:

    τ_k = τᵃ_{k−ℓ+1} − M̄ a_{k−ℓ} + M̄ (q̈_d,k + K_d ė_k + K_p e_k),   N̂_k = a_{k−ℓ} − τᵃ_{k−ℓ+1}/M̄

with the constants of the run's resolved config (`[controller]` m_bar, kp, kd,
tde_delay_samples; `[loop]` ts_s; `[sensor]` velocity). Run it in place of the built-in one:

    deltaloop run configs/s1-nominal.toml --mode lockstep --law tdc \\
        --controller-cmd "<venv>/bin/python examples/python-controller/controller.py"

The law is `deltaloop.tdc.Tdc` (python/deltaloop/tdc.py): its arithmetic follows law.rs
operation by operation, so a lockstep run gives the built-in controller's trace bit for bit.
"""

import sys

from deltaloop import Controller
from deltaloop.tdc import Tdc


def main():
    ctl = Controller(name="python-tdc")
    if ctl.law not in ("", "tdc"):
        # The run's files would carry the other law's name: refuse rather than mislabel.
        print(f"python-tdc: this example implements only tdc, not {ctl.law} (run with --law tdc)", file=sys.stderr)
        return 2
    try:
        law = Tdc(ctl.config)
    except (KeyError, ValueError) as e:
        print(f"python-tdc: the config lacks controller constant {e} (pass the resolved config)", file=sys.stderr)
        return 3
    return ctl.run(law.step)


if __name__ == "__main__":
    sys.exit(main())
