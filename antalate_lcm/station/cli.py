"""The station's subcommands: ``station`` (serve), ``station-key`` (make keys), ``command`` (an
operator's signed command over the station's API)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from antalate_lcm.base.errors import AntalateError

from ._settings import DEFAULT_HOST, DEFAULT_PORT


def cmd_station(args: argparse.Namespace) -> int:
    from ._file import load_station_file
    from ._server import run_station
    from ._settings import StationSettings, given_settings

    if args.config:
        f = load_station_file(args.config)
        settings, host, port, cert, key = f.settings, f.host, f.port, f.tls_cert, f.tls_key
    else:
        settings, host, port, cert, key = StationSettings(), DEFAULT_HOST, DEFAULT_PORT, None, None
    overrides = given_settings(
        args, (("db", "db_path"), ("range", "range_m"), ("fov", "fov_deg"), ("stale_after", "stale_after_s"))
    )
    if overrides:
        from pydantic import ValidationError

        try:
            settings = StationSettings.model_validate({**settings.model_dump(), **overrides})
        except ValidationError as exc:
            raise AntalateError(f"invalid station parameters: {exc}") from None
    run_station(
        host=args.host or host,
        port=args.port if args.port is not None else port,
        settings=settings,
        tls_cert=args.tls_cert or cert,
        tls_key=args.tls_key or key,
    )
    return 0


def _read_secret(path: str, what: str) -> str:
    try:
        text = Path(path).read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise AntalateError(f"cannot read the {what} from {path}: {exc.strerror or exc}") from None
    if not text:
        raise AntalateError(f"{path} is empty: expected the {what}")
    return text


def _swarm_key(args: argparse.Namespace) -> str | None:
    if getattr(args, "swarm_key_file", None):
        return _read_secret(args.swarm_key_file, "swarm key")
    if getattr(args, "agent_config", None):
        from antalate_lcm.core.config import load_config

        key = load_config(args.agent_config).security.swarm_key
        if not key:
            raise AntalateError(f"{args.agent_config} has no [security] swarm_key")
        return key
    return None


def cmd_station_key(args: argparse.Namespace) -> int:
    from ._auth import new_api_key, registration_key, sha256_hex

    if args.kind == "api":
        key = new_api_key()
        print(f"API key for {args.name!r} ({args.role}); it is shown only now, keep it secret:\n\n  {key}\n")
        print("Add to the station config (station.toml), then restart the station:\n")
        print(f'[[api_keys]]\nname = "{args.name}"\nrole = "{args.role}"\nsha256 = "{sha256_hex(key)}"')
        return 0
    swarm_key = _swarm_key(args)
    if swarm_key is None:
        raise AntalateError("give the swarm key: --swarm-key-file FILE or --agent-config AGENT.toml")
    print(
        "Registration key (derived from the swarm key; it cannot sign commands). Add to the station config:\n"
    )
    print(f'[station]\nregistration_key = "{registration_key(swarm_key)}"')
    return 0


def cmd_command(args: argparse.Namespace) -> int:
    from .client import StationClient, StationClientError

    api_key = args.api_key or os.environ.get("ANTALATE_API_KEY")
    if args.api_key_file:
        api_key = _read_secret(args.api_key_file, "API key")
    if not api_key:
        raise AntalateError("an API key is needed: --api-key-file FILE, --api-key KEY or $ANTALATE_API_KEY")
    swarm_key = _swarm_key(args)
    with StationClient(
        args.station, api_key, swarm_key=swarm_key, sender=args.sender, ca_file=args.ca_file
    ) as c:
        try:
            if args.action == "agents":
                result: object = c.agents()
            elif args.action == "direction":
                if args.azimuth is None:
                    raise AntalateError("direction needs --azimuth DEG (and --speed M/S)")
                result = c.direction(args.azimuth, args.speed, active=not args.stop, target=args.target)
            else:
                result = c.command(args.action, target=args.target, altitude=args.altitude)
        except StationClientError as exc:
            raise AntalateError(str(exc)) from None
        except ValueError as exc:
            raise AntalateError(str(exc)) from None
        except Exception as exc:  # httpx's connection errors: one line, not a traceback
            import httpx

            if isinstance(exc, httpx.HTTPError):
                raise AntalateError(f"cannot reach the station at {args.station}: {exc}") from None
            raise
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")
    if swarm_key is None and args.action != "agents":
        print(
            "antalate: the command went unsigned (no --swarm-key-file): agents with a swarm key drop it",
            file=sys.stderr,
        )
    return 0


def station_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="station config file (TOML: [station], [rate_limits], [[api_keys]])")
    p.add_argument(
        "--db", help="SQLite file (default: in the user's data directory; ':memory:' keeps nothing)"
    )
    p.add_argument("--host", help=f"address to listen on (default {DEFAULT_HOST})")
    p.add_argument("--port", type=int, help=f"port (default {DEFAULT_PORT})")
    p.add_argument("--range", type=float, help="front-sector sensing range, m (default 100)")
    p.add_argument("--fov", type=float, help="front-sector field of view, deg (default 60)")
    p.add_argument(
        "--stale-after", type=float, help="s without a report before an agent is stale (default 5)"
    )
    p.add_argument("--tls-cert", help="PEM certificate (chain): serve HTTPS")
    p.add_argument("--tls-key", help="PEM private key of --tls-cert")


def station_key_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "kind",
        choices=("api", "registration"),
        help="api: an operator's key; registration: the key derived from the swarm key",
    )
    p.add_argument("--name", default="operator", help="api: who holds the key (default operator)")
    p.add_argument(
        "--role", choices=("operator", "read-only"), default="operator", help="api: default operator"
    )
    p.add_argument("--swarm-key-file", help="registration: a file holding the swarm key")
    p.add_argument("--agent-config", help="registration: an agent config with [security] swarm_key")


def command_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "action",
        choices=("TAKEOFF", "LAND", "RTL", "direction", "agents"),
        help="a command, a direction (--azimuth, --speed) or 'agents' to list them",
    )
    p.add_argument("--station", required=True, help="station URL, e.g. https://192.168.1.10:8443")
    p.add_argument("--api-key", help="the API key (visible in the process list: prefer --api-key-file)")
    p.add_argument("--api-key-file", help="a file holding the API key (or set $ANTALATE_API_KEY)")
    p.add_argument("--swarm-key-file", help="a file holding the swarm key: the command is signed with it")
    p.add_argument("--agent-config", help="take the swarm key from this config's [security] swarm_key")
    p.add_argument("--target", help="an agent's name (default: every agent)")
    p.add_argument("--altitude", type=float, default=0.0, help="TAKEOFF altitude, m (default: the agent's)")
    p.add_argument("--azimuth", type=float, help="direction: degrees from north")
    p.add_argument("--speed", type=float, default=1.0, help="direction: m/s (default 1)")
    p.add_argument("--stop", action="store_true", help="direction: tell the agents to stop following one")
    p.add_argument("--sender", default="station-client", help="operator name in the signed header")
    p.add_argument("--ca-file", help="CA certificate (PEM) that signed the station's TLS certificate")
