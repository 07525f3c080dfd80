"""``gateway model``: inspect the vehicle model (modes, stability) at a speed."""

from __future__ import annotations

import argparse
import json

from gateway.cli import SPEED_MPS, real
from gateway.model.vehicle import (
    THETA_NOMINAL,
    Theta,
    VehicleParams,
    modes,
    stability,
    system_matrix,
)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("model", help="inspect the vehicle model")
    msub = parser.add_subparsers(dest="model_command", metavar="WHAT", required=True)
    p = msub.add_parser("modes", help="modal frequencies and damping ratios (paper Table 1)")
    # domains: speed 0.1-150 m/s; dampers up to ~250x nominal (Csy 40 kNs/m, Csay
    # 4.1 MNs/m); conicity up to 1 (0.05-0.6 on real wheel profiles)
    p.add_argument("--speed", type=SPEED_MPS, default=42.5, help="vehicle speed in m/s")
    p.add_argument("--csy", type=real(0.0, 1e7, lo_open=True),
                   default=THETA_NOMINAL.csy_ns_per_m,
                   help="lateral damping Csy in N s/m (default: Appendix nominal)")
    p.add_argument("--csay", type=real(0.0, 1e9, lo_open=True),
                   default=THETA_NOMINAL.csay_ns_per_m,
                   help="anti-yaw damping Csay in N s/m (default: Appendix nominal)")
    p.add_argument("--conicity", type=real(0.0, 1.0, lo_open=True),
                   default=THETA_NOMINAL.conicity,
                   help="equivalent conicity (default 0.15)")
    p.add_argument("--json", action="store_true", help="print a JSON list")
    p.set_defaults(func=run_modes)


def run_modes(args: argparse.Namespace) -> int:
    theta = Theta(args.csy, args.csay, args.conicity)
    A = system_matrix(VehicleParams(), theta, args.speed)
    found = modes(A)
    stab = stability(VehicleParams(), theta, args.speed)
    if args.json:
        print(json.dumps([{"frequency_hz": round(m.frequency_hz, 6),
                           "damping_ratio": round(m.damping_ratio, 6)} for m in found]))
        return 0
    print(f"speed {args.speed:g} m/s, Csy {theta.csy_ns_per_m:g} N s/m, "
          f"Csay {theta.csay_ns_per_m:g} N s/m, conicity {theta.conicity:g}")
    print(f"{'frequency [Hz]':>15} {'damping ratio':>14}")
    for m in found:
        print(f"{m.frequency_hz:15.3f} {m.damping_ratio:14.4f}")
    state = "stable" if stab.stable else "UNSTABLE"
    print(f"{state}: largest growth rate {stab.max_growth_rate_per_s:+.4f} 1/s")
    return 0
