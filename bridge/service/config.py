"""Service configuration: embedded defaults, a TOML file, command-line flags.

:class:`ServiceConfig` is a strict, frozen pydantic model. Sources are applied in order —
embedded defaults, then a TOML file (``--config``), then flags — and every value is
validated with an error naming the field and the allowed range
(:class:`ServiceConfigError`). The defaults give a working service with nothing else:
a Zenoh peer listening on ``tcp/127.0.0.1:7447`` with multicast scouting off, key prefix
``hitch``, the in-process simulated cylinder ECU on a python-can ``virtual`` bus, profile
``thesis-t132`` category 2, 50 Hz control, presets and maneuvers under
``$XDG_DATA_HOME/hitch-planner`` (``~/.local/share/hitch-planner``).

The implement has a third source, the selection the service persisted: ``implement_source`` says whether
``implement`` came from a flag (it comes before the persisted selection) or from the file (after it;
``docs/implements.md``).

TOML layout (every key optional; the names are the field names below; a relative path in the file — the
security file, the truth, the profile or field when given as a file, the data folder, the lines file, the
CAN log — is taken from the config file's folder)::

    [zenoh]    mode = "peer"; listen = ["tcp/127.0.0.1:7447"]; connect = []; prefix = "hitch"
               security = "/etc/hitch/zenoh-security.json5"; scouting = false
    [can]      interface = "virtual"; channel = "hitch"; simulate_ecu = true; stale_timeout_s = 0.2
               sim_ground_speed = 1.5   # m/s of the simulated tractor (wheel-based speed, PGN 65096)
               sim_truth = "truth.toml" # the simulated machine's own true profile (hitch sim perturb)
               hitch_status_address = 240   # the rear hitch status's (the lift's) sender, with simulate_ecu = false
                                            # (a tractor's TECU); absent: the cylinder ECU (169)
               hitch_status_period_s = 0.1  # its period; absent: 0.01 from the cylinder ECU, else 0.1 (ISO 11783-7)
    [hitch]    profile = "thesis-t132"; category = "2"; implement = "cat2-spreader-400";
               control_rate = 50.0; state_rate = 50.0
               feedforward = true   # stream the unit loops' feed-forward reference (bridge.link.unit_loop)
               following_error_lift_rad = 0.02; following_error_m = 0.01   # fault following_error: allowed
               following_error_lag_s = 0.3; following_error_s = 0.5        # error + lag x speed, for this long
    [service]  data_dir = "/var/lib/hitch"; http = "127.0.0.1:8080"; workers = 4; planning_processes = 2
               realtime = true   # the control path under SCHED_FIFO where permitted (bridge.service.scheduling)
               max_presets_per_user = 1000; max_maneuvers_per_user = 200
               max_script_bytes_per_user = 4194304   # the store's limits per user (store.StoreLimits)
               can_log = "bus.asc"; can_log_max_mb = 50.0; can_log_keep = 10   # CAN recorder, rotated by size
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from bridge.isobus.j1939 import CYLINDER_ECU_ADDRESS
from bridge.service.motion.following import LIMIT_RANGES, FollowingErrorLimits
from planner.errors import HitchInputError
from planner.profiles.loader import format_validation_error
from planner.textfile import read_text_file

if TYPE_CHECKING:
    from bridge.service.store import StoreLimits

__all__ = [
    "ServiceConfig",
    "ServiceConfigError",
    "DEFAULT_LISTEN",
    "default_data_dir",
    "load_service_config",
    "validate_prefix",
    "validate_endpoint",
]

#: Loopback only by default: nothing outside this machine reaches the service unless configured.
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
#: the Zenoh link lease a service and ``hitch router`` announce by default [s] (``[zenoh] lease_s``,
#: ``hitch router --lease-s``; Zenoh's own default is 10 s): a node that hears nothing from them this long closes
#: the link. With Zenoh's default a frozen router (SIGSTOP, a hung host, a half-open TCP link) was noticed by its
#: services only after 9 s, while nobody could stop the hitch through it (a fleet trial). Keep-alives go every
#: quarter of it. A radio link with longer gaps needs a longer lease (a router's lease decides when its services
#: count it lost and, with ``on_link_loss = "stop"``, brake).
DEFAULT_LEASE_S = 2.0
#: the period the simulated cylinder ECU sends the rear hitch status at [s] (``EcuNodeConfig.hitch_status_period_s``)
SIM_HITCH_STATUS_PERIOD_S = 0.01
#: the allowed lease range [s]
LEASE_RANGE_S = (0.5, 60.0)
#: the settings that are numbers: a boolean or text is refused for each, naming it (:meth:`ServiceConfig._number`)
NUMBER_FIELDS: tuple[str, ...] = (
    "lease_s",
    "stale_timeout_s",
    "hitch_status_address",
    "hitch_status_period_s",
    "sim_ground_speed",
    "sim_gnss_origin",
    "sim_gnss_heading",
    "control_rate",
    "state_rate",
    "following_error_lift_rad",
    "following_error_m",
    "following_error_lag_s",
    "following_error_s",
    "workers",
    "can_log_max_mb",
    "can_log_keep",
    "planning_processes",
    "max_presets_per_user",
    "max_maneuvers_per_user",
    "max_script_bytes_per_user",
)
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|unixsock-stream|ws)/[^\s]+$")
_CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")


class ServiceConfigError(HitchInputError):
    """A configuration value the service cannot use; the message names the field and the allowed values."""


def default_data_dir(environ: dict[str, str] | None = None) -> Path:
    """Per-user data folder: ``$XDG_DATA_HOME/hitch-planner`` or ``~/.local/share/hitch-planner``."""
    env = os.environ if environ is None else environ
    base = env.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "hitch-planner"


def validate_prefix(prefix: str) -> str:
    """A Zenoh key prefix without wildcards: chunks of ``[A-Za-z0-9_-.]`` separated by ``/``."""
    if not isinstance(prefix, str) or not prefix:
        raise ServiceConfigError("prefix must be a non-empty key expression such as 'hitch' or 'fleet/t07/hitch'")
    for chunk in prefix.split("/"):
        if not _CHUNK.match(chunk):
            raise ServiceConfigError(
                f"prefix {prefix!r}: chunk {chunk!r} is not allowed (letters, digits, '_', '-', '.'; "
                "no wildcards, no empty chunks)"
            )
    return prefix


def validate_endpoint(endpoint: str) -> str:
    """A Zenoh locator ``<protocol>/<address>`` (tcp, udp, tls, quic, unixsock-stream, ws)."""
    if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint):
        raise ServiceConfigError(
            f"endpoint {endpoint!r} must look like 'tcp/127.0.0.1:7447' "
            "(protocol tcp, udp, tls, quic, unixsock-stream or ws)"
        )
    if not endpoint.startswith("unixsock-stream/"):  # the port, said here ("invalid port value" from Zenoh)
        address = re.split(r"[?#]", endpoint.split("/", 1)[1], maxsplit=1)[0]
        port = address.rsplit(":", 1)[1] if ":" in address else ""
        if not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ServiceConfigError(
                f"endpoint {endpoint!r}: the port {port or '(none)'!s} must be a whole number 0…65535 "
                "(e.g. tcp/127.0.0.1:7447)"
            )
    return endpoint


def _following(name: str) -> Any:
    """A following-error setting: the default and range of that field of
    :class:`~bridge.service.motion.following.FollowingErrorLimits`, its unit from the name's suffix."""
    lo, hi = LIMIT_RANGES[name]
    unit = name.rsplit("_", 1)[1]
    return Field(getattr(FollowingErrorLimits(), name), ge=lo, le=hi, strict=True, json_schema_extra={"unit": unit})


def _unit(unit: str) -> dict[str, Any]:
    """A field's unit, said with its allowed range in an error (:func:`format_validation_error`)."""
    return {"unit": unit}


class ServiceConfig(BaseModel):
    """Everything one service instance needs; SI units (rates in Hz, times in s)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: Literal["peer", "client"] = "peer"
    #: default: DEFAULT_LISTEN for a peer, nothing for a client (a client connects, it does not listen)
    listen: tuple[str, ...] | None = None
    connect: tuple[str, ...] = ()
    prefix: str = "hitch"
    #: multicast scouting (off by default: loopback only, no discovery traffic)
    scouting: bool = Field(False, strict=True)
    #: when every node of ``connect`` (the router, for a client) is lost: "stop" brakes any motion to rest (the
    #: fleet can no longer stop it; an event says so either way), "continue" lets it run on (docs/faults.md)
    on_link_loss: Literal["stop", "continue"] = "stop"
    #: the Zenoh link lease this service announces [s] (:data:`DEFAULT_LEASE_S`): how long a router or a client
    #: waits for word from it before it counts the link lost
    lease_s: float = Field(
        DEFAULT_LEASE_S, ge=LEASE_RANGE_S[0], le=LEASE_RANGE_S[1], strict=True, json_schema_extra=_unit("s")
    )
    #: Zenoh security config (JSON5: usrpwd, access_control, TLS) merged into the session config
    security: Path | None = None
    #: serve each user's own request keys (``<prefix>/user/<name>/<key>``: admission, store owner and black box
    #: per user; docs/security.md); "auto": when this service's own access control checks the names
    user_keys: Literal["auto"] | Annotated[bool, Strict()] = "auto"
    can_interface: Literal["virtual", "socketcan", "udp_multicast", "remote"] = "virtual"
    can_channel: str = "hitch"
    #: run the simulated cylinder ECU in this process on the same bus
    simulate_ecu: bool = Field(True, strict=True)
    stale_timeout_s: float = Field(0.2, ge=0.05, le=2.0, strict=True, json_schema_extra=_unit("s"))
    #: the source address the link takes the ISO 11783-7 rear hitch status (the lift) from, 0..253; None: the
    #: cylinder ECU (169; its simulated twin sends it). A tractor whose TECU sends it: its address (thesis: 240)
    #: (bridge.link.state.LinkConfig.hitch_status_address)
    hitch_status_address: int | None = Field(None, ge=0, le=253, strict=True)
    #: the period the rear hitch status is sent at [s]; None: 0.01 from the cylinder ECU (its twin sends it with
    #: every 0xFF22), 0.1 from another sender (ISO 11783-7). Frames arriving 1.8 × faster are a second node
    #: sending as its address (bridge.link.arrival_rate; a review: a spoof at 150/s passed beside a 10 Hz TECU
    #: taken as a 100 Hz sender) (bridge.link.state.LinkConfig.hitch_status_period_s)
    hitch_status_period_s: float | None = Field(None, ge=0.001, le=1.0, strict=True, json_schema_extra=_unit("s"))
    #: ground speed of the simulated tractor (PGN 65096, for maneuver ``wait_for``) [m/s]
    sim_ground_speed: float = Field(1.5, ge=0.0, le=20.0, strict=True, json_schema_extra=_unit("m/s"))
    #: the simulated machine's own truth profile (bridge.sim.truth); None: the planner's profile exactly
    sim_truth: Path | None = None
    #: the simulated tractor drives over this field (bridge.sim.field: a built-in name or a .toml path) and
    #: the twin's draft pins send its draft (bridge.service.work); None: flat ground, no draft
    sim_field: str | None = None
    #: the simulated tractor drives over this track scenario's terrain, slope and row signal (bridge.sim.scenario:
    #: a built-in name such as "levelling" or a .toml path), without draft: levelling, guidance and terrain
    #: following can be tried on the service; None: flat ground (or sim_field's terrain). Not with sim_field
    sim_scenario: str | None = None
    #: the simulated tractor's GNSS (hitch/tractor/gnss, bridge.service.gnss.TwinGnss): its start (lat, lon [deg])
    #: and its straight course (clockwise from north [rad]; default due east)
    sim_gnss_origin: tuple[Annotated[float, Strict()], Annotated[float, Strict()]] = (48.0, 11.0)
    sim_gnss_heading: float = Field(
        math.pi / 2, ge=-2 * math.pi, le=2 * math.pi, allow_inf_nan=False, strict=True, json_schema_extra=_unit("rad")
    )
    #: GeoJSON field lines loaded (and saved in the store) at start-up (maneuver wait_for line)
    lines_file: Path | None = None
    profile: str = "thesis-t132"
    category: str | None = None
    implement: str | None = None
    #: where ``implement`` came from: "flag" (``hitch serve --implement``: it wins over the selection the store
    #: persisted) or "file" (the config file, or a program's own config: the persisted selection wins over it;
    #: docs/implements.md). Not a key of the file: :func:`load_service_config` sets it
    implement_source: Literal["file", "flag"] = "file"
    control_rate: float = Field(50.0, ge=10.0, le=200.0, strict=True, json_schema_extra=_unit("Hz"))
    state_rate: float = Field(50.0, ge=1.0, le=100.0, strict=True, json_schema_extra=_unit("Hz"))
    #: stream the unit loops' feed-forward reference (False: the plan's actuators as they are)
    feedforward: bool = Field(True, strict=True)
    #: following-error supervision (fault following_error; bridge.service.motion.following): allowed error at rest
    #: of the lift [rad] and of the other actuators [m], extra allowance per unit of reference speed [s], and how long
    #: an error beyond it is borne [s]
    following_error_lift_rad: float = _following("lift_rad")
    following_error_m: float = _following("length_m")
    following_error_lag_s: float = _following("lag_s")
    following_error_s: float = _following("time_s")
    data_dir: Path = Field(default_factory=default_data_dir)
    http: str | None = None
    #: further HOST:PORT names the terminal is reached by (its address and loopback always are; a name is refused
    #: otherwise: DNS-rebinding protection, docs/operator_terminal.md), e.g. ("cab-display.local:8080",)
    http_hosts: tuple[str, ...] = ()
    #: the user the web terminal's commands run as when it has no login (no access control); ignored, with a
    #: warning, when it has one (a users file); with access control and no users file the terminal refuses to start
    http_user: str | None = None
    workers: int = Field(4, ge=1, le=32, strict=True)
    #: where the control core runs: "process" (its own, bridge.service.core) or "thread" (in the service's)
    control_core: Literal["process", "thread"] = "process"
    #: run the control path under the real-time policy SCHED_FIFO where permitted (bridge.service.scheduling);
    #: False: raised nice values only
    realtime: bool = Field(True, strict=True)
    #: record every CAN frame to this file (.asc, .blf, candump .log, .csv; python-can's writers), rotated
    #: at can_log_max_mb megabytes (10^6 bytes) a file, can_log_keep rotated files kept (bridge.service.blackbox)
    can_log: Path | None = None
    can_log_max_mb: float = Field(50.0, ge=0.1, le=100_000.0, strict=True, json_schema_extra=_unit("MB"))
    can_log_keep: int = Field(10, ge=1, le=1000, strict=True)
    #: processes for plan previews, maneuver validation and IK (bridge.service.workers); 0: on the worker threads
    planning_processes: int = Field(2, ge=0, le=32, strict=True)
    #: per-user limits of the presets and maneuvers store (see bridge.service.store.StoreLimits)
    max_presets_per_user: int = Field(1000, ge=1, le=100_000, strict=True)
    max_maneuvers_per_user: int = Field(200, ge=1, le=10_000, strict=True)
    max_script_bytes_per_user: int = Field(
        4 * 1024 * 1024, ge=64 * 1024, le=1024**3, strict=True, json_schema_extra=_unit("bytes")
    )

    @field_validator("prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        return validate_prefix(v)

    @field_validator("listen", "connect", mode="before")
    @classmethod
    def _endpoint_list(cls, v: Any, info: ValidationInfo) -> Any:
        if isinstance(v, str):  # (pydantic said "Input should be a valid tuple")
            raise ServiceConfigError(
                f'{info.field_name} must be a list of endpoints such as ["tcp/127.0.0.1:7447"], got the string {v!r}'
            )
        return v

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: tuple[str, ...] | None) -> tuple[str, ...] | None:
        return None if v is None else tuple(validate_endpoint(e) for e in v)

    @field_validator("user_keys", mode="before")
    @classmethod
    def _user_keys(cls, v: Any) -> Any:
        if v != "auto" and not isinstance(v, bool):  # (pydantic named its literal['auto'] and bool branches)
            raise ServiceConfigError(f'user_keys must be "auto", true or false, got {v!r}')
        return v

    @field_validator(*NUMBER_FIELDS, mode="before")
    @classmethod
    def _number(cls, v: Any, info: ValidationInfo) -> Any:
        # a boolean is no number (pydantic's lax mode read stale_timeout_s = true as 1.0 s, a fuzz trial), nor is
        # text; the error line adds the allowed range with its unit
        pair = info.field_name == "sim_gnss_origin"
        for x in v if pair and isinstance(v, (list, tuple)) else (v,):
            if x is None or (isinstance(x, (int, float)) and not isinstance(x, bool)):
                continue
            if isinstance(x, bool):
                got = f"{str(x).lower()} (a boolean)"
            elif isinstance(x, str):
                got = f"the text {x[:40]!r}" + ("…" if len(x) > 40 else "") + " (a number is written without quotes)"
            else:
                kind = "table" if isinstance(x, dict) else "list" if isinstance(x, (list, tuple)) else type(x).__name__
                got = f"a {kind}"
            what = "two numbers (lat, lon in deg)" if pair else "a number"
            raise ServiceConfigError(f"must be {what}, got {got}")
        return v

    @field_validator("stale_timeout_s", "control_rate", "state_rate", "sim_ground_speed")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ServiceConfigError("must be a finite number")
        return v

    @field_validator("sim_gnss_origin")
    @classmethod
    def _sim_gnss_origin(cls, v: tuple[float, float]) -> tuple[float, float]:
        lat, lon = v
        if not (math.isfinite(lat) and math.isfinite(lon) and -85 <= lat <= 85 and -180 <= lon <= 180):
            raise ServiceConfigError(f"sim_gnss_origin must be (lat in [-85, 85], lon in [-180, 180]) deg, got {v!r}")
        return v

    @field_validator("sim_truth")
    @classmethod
    def _sim_truth(cls, v: Path | None) -> Path | None:
        if v is not None and not v.is_file():
            raise ServiceConfigError(f"sim_truth {str(v)!r} must be an existing truth profile file (.toml)")
        return v

    @field_validator("sim_scenario")
    @classmethod
    def _sim_scenario(cls, v: str | None) -> str | None:
        if v is None:
            return v
        from bridge.sim.scenario import ScenarioError, load_scenario

        try:
            load_scenario(v)  # named now: a bad file refused before the service starts, naming the key
        except ScenarioError as exc:
            raise ServiceConfigError(f"sim_scenario {v!r}: {exc}") from None
        return v

    @model_validator(mode="after")
    def _one_terrain(self) -> ServiceConfig:
        if self.sim_field is not None and self.sim_scenario is not None:
            raise ServiceConfigError(
                f"sim_field {self.sim_field!r} and sim_scenario {self.sim_scenario!r}: give one (a field drives over "
                "its own scenario, named by its file's scenario key)"
            )
        return self

    @field_validator("http")
    @classmethod
    def _http(cls, v: str | None) -> str | None:
        if v is not None and (not re.match(r"^[^\s:]+:\d{1,5}$", v) or int(v.rsplit(":", 1)[1]) > 65535):
            raise ServiceConfigError(f"http {v!r} must be HOST:PORT, e.g. 127.0.0.1:8080 (port 0…65535)")
        return v

    @field_validator("http_hosts")
    @classmethod
    def _http_hosts(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        for h in v:
            if not re.match(r"^(\[[0-9A-Fa-f:.]+\]|[^\s:\[\]]+):\d{1,5}$", h) or int(h.rsplit(":", 1)[1]) > 65535:
                raise ServiceConfigError(
                    f"http_hosts {h!r} must be HOST:PORT, e.g. cab-display.local:8080 (port 0…65535)"
                )
        return v

    @model_validator(mode="after")
    def _mode_endpoints(self) -> ServiceConfig:
        if self.listen is None:
            object.__setattr__(self, "listen", (DEFAULT_LISTEN,) if self.mode == "peer" else ())
        elif self.mode == "client" and self.listen:
            raise ServiceConfigError("listen: a client does not listen (mode = 'client'); give connect endpoints only")
        if self.mode == "client" and not self.connect:
            raise ServiceConfigError("connect: a client needs at least one endpoint to connect to (a router or a peer)")
        if self.simulate_ecu and self.hitch_status_address not in (None, CYLINDER_ECU_ADDRESS):
            raise ServiceConfigError(
                f"hitch_status_address {self.hitch_status_address}: the simulated cylinder ECU (simulate_ecu = true) "
                f"sends the rear hitch status from {CYLINDER_ECU_ADDRESS}; leave hitch_status_address unset, or set "
                "simulate_ecu = false for a tractor that sends it"
            )
        period = self.hitch_status_period()
        if self.simulate_ecu and period != SIM_HITCH_STATUS_PERIOD_S:
            raise ServiceConfigError(
                f"hitch_status_period_s {period:g} s: the simulated cylinder ECU (simulate_ecu = true) sends the rear "
                f"hitch status every {SIM_HITCH_STATUS_PERIOD_S:g} s; leave hitch_status_period_s unset, or set "
                "simulate_ecu = false for a sender of another period"
            )
        if period >= self.stale_timeout_s:
            default = (
                " (its default from a sender other than the cylinder ECU)" if self.hitch_status_period_s is None else ""
            )
            raise ServiceConfigError(
                f"hitch_status_period_s {period:g} s{default}: not below stale_timeout_s = "
                f"{self.stale_timeout_s:g} s (the lift would be stale between any two frames); a shorter period, or a "
                "longer stale_timeout_s"
            )
        return self

    def hitch_status_period(self) -> float:
        """The rear hitch status's period the link expects [s] (``hitch_status_period_s``, or its default: 0.01
        from the cylinder ECU, 0.1 from another sender)."""
        if self.hitch_status_period_s is not None:
            return self.hitch_status_period_s
        return SIM_HITCH_STATUS_PERIOD_S if self.hitch_status_address in (None, CYLINDER_ECU_ADDRESS) else 0.1

    def key(self, name: str) -> str:
        """Full key of an API name: ``key("goto")`` → ``"hitch/goto"``."""
        return f"{self.prefix}/{name}"

    @property
    def database_path(self) -> Path:
        """The SQLite file of presets and maneuvers."""
        return self.data_dir / "hitch.sqlite3"

    def store_limits(self) -> StoreLimits:
        """The store's per-user limits (``HitchStore(config.database_path, limits=config.store_limits())``)."""
        from bridge.service.store import StoreLimits  # the store loads only when a service runs

        return StoreLimits(self.max_presets_per_user, self.max_maneuvers_per_user, self.max_script_bytes_per_user)


_TOML_SECTIONS = {
    "zenoh": {
        "mode": "mode",
        "listen": "listen",
        "on_link_loss": "on_link_loss",
        "lease_s": "lease_s",
        "connect": "connect",
        "prefix": "prefix",
        "security": "security",
        "scouting": "scouting",
        "user_keys": "user_keys",
    },
    "can": {
        "interface": "can_interface",
        "channel": "can_channel",
        "simulate_ecu": "simulate_ecu",
        "stale_timeout_s": "stale_timeout_s",
        "hitch_status_address": "hitch_status_address",
        "hitch_status_period_s": "hitch_status_period_s",
        "sim_ground_speed": "sim_ground_speed",
        "sim_truth": "sim_truth",
        "sim_field": "sim_field",
        "sim_scenario": "sim_scenario",
        "sim_gnss_origin": "sim_gnss_origin",
        "sim_gnss_heading": "sim_gnss_heading",
    },
    "hitch": {
        "profile": "profile",
        "category": "category",
        "implement": "implement",
        "control_rate": "control_rate",
        "state_rate": "state_rate",
        "feedforward": "feedforward",
        "following_error_lift_rad": "following_error_lift_rad",
        "following_error_m": "following_error_m",
        "following_error_lag_s": "following_error_lag_s",
        "following_error_s": "following_error_s",
    },
    "service": {
        "data_dir": "data_dir",
        "http": "http",
        "http_hosts": "http_hosts",
        "http_user": "http_user",
        "workers": "workers",
        "planning_processes": "planning_processes",
        "control_core": "control_core",
        "realtime": "realtime",
        "lines_file": "lines_file",
        "max_presets_per_user": "max_presets_per_user",
        "max_maneuvers_per_user": "max_maneuvers_per_user",
        "max_script_bytes_per_user": "max_script_bytes_per_user",
        "can_log": "can_log",
        "can_log_max_mb": "can_log_max_mb",
        "can_log_keep": "can_log_keep",
    },
}


def _flatten_toml(data: dict, source: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for section, values in data.items():
        if section not in _TOML_SECTIONS:
            home = [name for name, keys in _TOML_SECTIONS.items() if section in keys]
            if home and not isinstance(values, dict):  # a key above every table (a fuzz trial: "unknown section")
                raise ServiceConfigError(
                    f"invalid service config {source}: {section} is a key of [{home[0]}]: put it under that table"
                )
            raise ServiceConfigError(
                f"invalid service config {source}: unknown section [{section}]; allowed: {', '.join(_TOML_SECTIONS)}"
            )
        if not isinstance(values, dict):
            raise ServiceConfigError(f"invalid service config {source}: {section} must be a table")
        for k, v in values.items():
            if k not in _TOML_SECTIONS[section]:
                raise ServiceConfigError(
                    f"invalid service config {source}: unknown key {section}.{k}; allowed: "
                    f"{', '.join(_TOML_SECTIONS[section])}"
                )
            out[_TOML_SECTIONS[section][k]] = v
    return out


#: config keys that are files or folders: a relative one in a config file is taken from the file's folder
_PATH_KEYS = ("security", "sim_truth", "lines_file", "data_dir", "can_log")
#: config keys that are a built-in name or a file: taken from the file's folder when they name a file
_NAME_OR_PATH_KEYS = ("profile", "sim_field", "sim_scenario")


def _from_folder(values: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``values`` of a config file with its relative paths taken from ``folder`` (the file's): a config file
    names its profile and truth as the profile names its tractor, from where it lies, not from where the
    service was started (a commissioning engineer's report: ``profile = "../tractor.toml"`` did not exist)."""
    out = dict(values)
    for k, v in values.items():
        if not isinstance(v, str) or not v:
            continue
        p = Path(v).expanduser()
        named_file = k in _NAME_OR_PATH_KEYS and (p.suffix == ".toml" or len(p.parts) > 1)
        if (k in _PATH_KEYS or named_file) and not p.is_absolute():
            out[k] = str(folder / p)
    return out


def load_service_config(path: str | Path | None = None, **overrides: Any) -> ServiceConfig:
    """Defaults, then the TOML file at ``path`` (if any; its relative paths from its own folder), then
    ``overrides`` (None values are ignored; relative paths from the working folder, as flags are)."""
    values: dict[str, Any] = {}
    source = "flags"
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ServiceConfigError(f"service config file {p} does not exist")
        source = str(p)
        # not UTF-8: "service config FILE: not UTF-8 text (byte N, …)", as the profile and scenario loaders say
        text = read_text_file(p, "service config", ServiceConfigError)  # (a UnicodeDecodeError traceback before)
        try:
            data = _flatten_toml(tomllib.loads(text), source)
        except tomllib.TOMLDecodeError as exc:
            raise ServiceConfigError(f"service config {p} is not valid TOML: {exc}") from None
        values.update(_from_folder(data, p.parent))
    given = {k: v for k, v in overrides.items() if v is not None}
    for flag, other in (("sim_field", "sim_scenario"), ("sim_scenario", "sim_field")):
        if flag in given and other not in given:  # a flag's terrain wins over the file's other one (one of the two)
            values.pop(other, None)
    values.update(given)
    if "implement" in given:  # a flag's implement wins over the persisted selection, the file's does not
        values.setdefault("implement_source", "flag")
    # a value from the file is named as the file names it: its table and key (can.stale_timeout_s)
    in_file = {f: f"{t}.{k}" for t, keys in _TOML_SECTIONS.items() for k, f in keys.items() if f in values}
    in_file = {f: name for f, name in in_file.items() if f not in given} if path is not None else {}
    try:
        return ServiceConfig.model_validate(values)
    except ValidationError as exc:
        lines = format_validation_error("service config", source, exc, ServiceConfig).splitlines()[1:]
        raise ServiceConfigError(
            f"invalid service config ({source}): "
            + "; ".join(_toml_name(ln.strip().removeprefix("<root>: "), in_file) for ln in lines)
        ) from None


def _toml_name(line: str, in_file: dict[str, str]) -> str:
    """An error ``line`` of :func:`format_validation_error` with its field named as the file names it."""
    m = re.match(r"^([a-z_]+)(?=[ .:\[])", line)
    if m is None or m.group(1) not in in_file:
        return line
    return in_file[m.group(1)] + line[m.end() :]
