"""Connect: the serial ports with their descriptions, the protocol, the unit's info and link health."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.widgets import Footer, Header, OptionList, Static
from textual.widgets.option_list import Option

from drivers.ports import SerialPort, list_serial_ports
from protocols.registry import DECODERS
from station.common.text import printable
from station.errors import StationError
from station.tui.messages import LinkFailed, Snapshot
from station.tui.screens.station_screen import StationScreen
from station.tui.session import SIMULATED, Session, open_session

# What the unit says of itself (its info keys), as the operator reads it.
INFO = (("serial", "serial", ""), ("model", "model", ""), ("firmware", "firmware", ""),
        ("rate_hz", "rate", " Hz"))


class ConnectScreen(StationScreen):
    """The ports to choose from, the unit once connected (its info and link health), the protocol."""

    BINDINGS = [
        Binding("enter", "continue", "continue", show=True),
        Binding("c", "choose", "other port"),
        Binding("p", "protocol", "protocol"),
    ]
    DEFAULT_CSS = """
    ConnectScreen #ports { height: auto; max-height: 12; border: round $accent; }
    ConnectScreen #info { border: round $secondary; height: auto; padding: 0 1; }
    ConnectScreen #hint { color: $text-muted; padding: 0 1; }
    """

    def compose(self) -> ComposeResult:
        """The hint, the ports, the unit's info, the keys."""
        yield Header()
        with Vertical():
            yield Static("", id="hint")
            yield OptionList(id="ports")
            yield Static("not connected", id="info")
        yield Footer()

    def on_mount(self) -> None:
        """List the ports; connect at once to --port or the simulated unit when given."""
        self.title = "imu-station · connect"
        ports = self.query_one("#ports", OptionList)
        simulator = SerialPort(SIMULATED, "the station's simulator (no hardware)")
        ports.add_option(Option(simulator.line(), id=SIMULATED))
        for p in list_serial_ports():
            ports.add_option(Option(Text(p.line()), id=p.device))
        ports.highlighted = 0
        ports.focus()
        self.show_hint()
        config = self.station.config
        self.given_protocol = config.protocol  # frame:FILE.yaml (--protocol) stays among those p offers
        if config.simulate or config.port:
            self.connect(SIMULATED if config.simulate else config.port)
        self.set_interval(0.5, self.show_link)

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        """Enter on a port: connect to it."""
        self.connect(event.option.id)

    def connect(self, port: str | None) -> None:
        """Close any open session and open ``port`` in a worker."""
        if self.station.session is not None:
            self.station.close_session()
        self.query_one("#info", Static).update(f"connecting to {port} ...")
        self.query_one("#ports", OptionList).disabled = True
        self._open(port)

    @work(thread=True, exclusive=True, group="connect")
    def _open(self, port: str | None) -> None:
        try:
            session = open_session(self.station.config, port)
        except (StationError, OSError) as exc:  # the port, or --supply / --table (DriverError is one)
            self.post_message(LinkFailed(exc))
            return
        self.post_message(Snapshot({"session": session}))

    def on_snapshot(self, message: Snapshot) -> None:
        """The port opened: keep its session and show the unit."""
        session: Session = message.data["session"]
        self.station.session = session
        self.station.connect_error = None
        self.show_hint()
        self.show_link()

    def on_link_failed(self, message: LinkFailed) -> None:
        """The port could not be opened: say why, and let another be chosen (quitting now exits with
        the error's code)."""
        self.station.connect_error = message.error
        self.query_one("#info", Static).update(f"[red]{message.error}[/red]\nChoose a port and press Enter.")
        ports = self.query_one("#ports", OptionList)
        ports.disabled = False
        ports.focus()

    def show_link(self) -> None:
        """The unit's info and the link's health (redrawn twice a second)."""
        session = self.station.session
        if session is None:
            return
        stats = session.device.stats
        table = Table.grid(padding=(0, 2))
        table.add_column(style="bold")
        table.add_column()
        table.add_row("port", session.name)
        table.add_row("protocol", session.device.protocol)
        for key, label, unit in INFO:
            value = session.info.get(key)
            table.add_row(label, Text(printable("?" if value is None else f"{value}{unit}")))
        health = "[green]good[/green]" if stats.errors == 0 and stats.lost == 0 else "[yellow]errors[/yellow]"
        table.add_row("link", f"{health}  {stats.rate_hz:.0f} Hz, {stats.samples} samples, "
                      f"{stats.errors} errors, {stats.lost} lost, {stats.overflow_drops} dropped")
        if session.power is not None:
            supply = session.power.supply.url
            table.add_row("supply", Text(f"{supply}: powers the unit (turn-ons power-cycle it)"))
        if session.table is not None:
            mounted = session.table
            table.add_row("table", Text(f"{mounted.table.url}: unit {mounted.mount} along its axis "
                                        "(the wizard's steps are the table's)"))
        self.query_one("#info", Static).update(table)

    def action_continue(self) -> None:
        """Enter once connected: the live view."""
        if self.station.session is not None:
            self.station.show("live")

    def action_choose(self) -> None:
        """``c``: choose another port."""
        ports = self.query_one("#ports", OptionList)
        ports.disabled = False
        ports.focus()

    def action_protocol(self) -> None:
        """``p``: the next protocol of the registry, or the one ``--protocol`` gave (``frame:FILE.yaml``)."""
        names = sorted(set(DECODERS) | {self.given_protocol})
        config = self.station.config
        config.protocol = names[(names.index(config.protocol) + 1) % len(names)] if config.protocol in names \
            else names[0]
        self.show_hint()

    def show_hint(self) -> None:
        """What Enter does now, and the protocol."""
        protocol = self.station.config.protocol
        if self.station.session is None:
            text = f"Choose the unit's port and press Enter.   protocol: {protocol} (p: change)"
        else:
            text = f"Connected. Enter: live view · c: another port · p: protocol ({protocol}) · ?: help"
        self.query_one("#hint", Static).update(text)
