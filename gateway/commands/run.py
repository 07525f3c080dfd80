"""``gateway run``: the daemon (systemd's ExecStart), with config overrides."""

from __future__ import annotations

import argparse
import logging

from gateway.cli import SEED, config_value
from gateway.config import Config, load_config, with_overrides
from gateway.service.daemon import Service

log = logging.getLogger(__name__)


def _bus_spec(text: str) -> str:
    iface, _, channel = text.partition(":")
    for key, value in (("interface", iface), ("channel", channel or "railgw")):
        config_value("bus", key)(value)
    return text


def add_overrides(p: argparse.ArgumentParser, *, live: bool = True) -> None:
    """Command-line overrides shared by run and replay; each checked against its config
    key's domain. ``live``: also the bus and the state directory (replay has neither:
    it reads a log and keeps no state, so it refuses them rather than ignore them)."""
    p.add_argument("--config", metavar="FILE", help="TOML configuration (default: built-in)")
    if live:
        p.add_argument("--bus", metavar="IFACE:CHANNEL", type=_bus_spec,
                       help="override [bus], e.g. virtual:railgw")
        p.add_argument("--state-dir", metavar="DIR", type=config_value("state", "directory"),
                       help="override [state] directory")
    p.add_argument("--particles", type=config_value("estimator", "particles"),
                   help="override [estimator] particles")
    p.add_argument("--sensors", type=int, choices=(3, 5), help="override [estimator] sensors")
    p.add_argument("--seed", type=SEED, help="override [estimator] seed")
    p.add_argument("--track-roughness", type=config_value("estimator", "track_roughness"),
                   metavar="AR",
                   help="override [estimator] track_roughness (Ar as printed in the paper)")
    p.add_argument("--estimate-ar", action="store_true", default=None,
                   help="estimate Ar jointly as a 4th parameter")
    p.add_argument("--drift", type=config_value("estimator", "drift_per_sqrt_s"),
                   metavar="REL", dest="drift",
                   help="override [estimator] drift_per_sqrt_s (0: static parameters)")


def overrides_of(args: argparse.Namespace) -> dict[str, object]:
    out: dict[str, object] = {}
    if getattr(args, "bus", None):
        iface, _, channel = args.bus.partition(":")
        out["bus.interface"] = iface
        out["bus.channel"] = channel or "railgw"
    for attr, key in (("state_dir", "state.directory"), ("particles", "estimator.particles"),
                      ("sensors", "estimator.sensors"), ("seed", "estimator.seed"),
                      ("track_roughness", "estimator.track_roughness"),
                      ("estimate_ar", "estimator.estimate_track_roughness"),
                      ("drift", "estimator.drift_per_sqrt_s")):
        value = getattr(args, attr, None)
        if value is not None:
            out[key] = value
    return out


def config_from_args(args: argparse.Namespace) -> Config:
    """The configuration file (or defaults) with the command-line overrides applied."""
    cfg = load_config(args.config)
    extra = overrides_of(args)
    return with_overrides(cfg, extra) if extra else cfg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the gateway service (systemd ExecStart)")
    add_overrides(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    service = Service(config_from_args(args), config_path=args.config)
    service.install_signal_handlers()
    return service.run()
