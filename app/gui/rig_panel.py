"""Rig tab: choose the instruments (a built-in simulated rig, a rig file, or real instruments on serial ports
and ``socket://`` URLs), see who answered ``*IDN?``, the link health and the output state, set the abort limits
and arm."""
from __future__ import annotations

import html

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (QButtonGroup, QCheckBox, QComboBox, QDoubleSpinBox, QFileDialog, QFormLayout,
                               QGridLayout, QGroupBox, QHBoxLayout, QLabel, QLineEdit, QListWidget, QPushButton,
                               QRadioButton, QSpinBox, QVBoxLayout, QWidget)

from drivers.discovery import serial_ports
from drivers.interfaces import Protection
from drivers.simulation.rig import builtin_rigs

from .lab import InstrumentStatus, Lab

OUTPUT_ON_STYLE = "background:#d62728; color:white; font-weight:bold; padding:4px"
OUTPUT_OFF_STYLE = "background:#2ca02c; color:white; font-weight:bold; padding:4px"
ARMED_STYLE = "color:#d62728; font-weight:bold"


def _value_label() -> QLabel:
    label = QLabel("—")
    label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
    label.setWordWrap(True)
    return label


def protection_text(protection: Protection) -> str:
    """One line per event: a green tick and what protects, or a red cross and "nothing"."""
    rows = []
    for event, by in protection.lines():
        mark = ('<span style="color:#2ca02c">&#10003;</span>' if by
                else '<span style="color:#d62728; font-weight:bold">&#10007;</span>')
        rows.append(f"{mark} {html.escape(event, quote=False)}: {html.escape(by or 'nothing', quote=False)}")
    return "<br>".join(rows)


class RigPanel(QWidget):
    """The Rig tab (module docstring)."""

    def __init__(self, lab: Lab, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        columns = QHBoxLayout(self)
        left, right = QVBoxLayout(), QVBoxLayout()
        columns.addLayout(left, 3)
        columns.addLayout(right, 2)
        left.addWidget(self._source_box())
        left.addWidget(self._identity_box())
        left.addWidget(self._safety_box())
        left.addStretch(1)
        right.addWidget(self._output_box())
        right.addWidget(self._health_box())
        right.addWidget(self._arm_box())
        right.addStretch(1)

        lab.instrumentsChanged.connect(self._show_instruments)
        lab.instrumentsBusy.connect(self._show_busy)
        lab.statusPolled.connect(self._show_status)
        lab.armedChanged.connect(self._show_armed)
        lab.limitsChanged.connect(self._show_limits)
        lab.campaignStarted.connect(lambda _: self._update_enabled())
        lab.campaignFinished.connect(lambda *_: self._update_enabled())
        lab.planChecked.connect(lambda ok, msg: self.plan_state.setText(msg))
        self._show_instruments()

    # ------------------------------------------------------------------ layout
    def _source_box(self) -> QGroupBox:
        box = QGroupBox("Instruments")
        grid = QGridLayout(box)
        self.source_group = QButtonGroup(self)
        self.use_builtin = QRadioButton("Built-in simulated rig")
        self.use_file = QRadioButton("Rig file (simulated)")
        self.use_real = QRadioButton("Real instruments")
        for i, button in enumerate((self.use_builtin, self.use_file, self.use_real)):
            self.source_group.addButton(button, i)
        self.use_builtin.setChecked(True)

        self.builtin_rig = QComboBox()
        self.builtin_rig.addItems(builtin_rigs())
        self.paced = QCheckBox("real time (paced)")
        self.paced.setToolTip("Run the emulated rig in real time instead of as fast as the host reads")
        self.seed = QSpinBox()
        self.seed.setRange(0, 2**31 - 1)
        self.seed.setPrefix("seed ")
        self.rig_file = QLineEdit()
        self.rig_file.setPlaceholderText("rig TOML file")
        browse = QPushButton("Browse…")
        browse.clicked.connect(self._browse_rig)

        self.shaker_url = QComboBox(editable=True)
        self.daq_url = QComboBox(editable=True)
        for combo, hint in ((self.shaker_url, "shaker controller: /dev/ttyUSB0, COM4, socket://host:port"),
                            (self.daq_url, "DAQ: port name or pyserial URL")):
            combo.lineEdit().setPlaceholderText(hint)
            combo.setMinimumContentsLength(24)
        self.excitation = QLineEdit()
        self.excitation.setPlaceholderText("force gauge DOF, e.g. A.w")
        self.sensors = QLineEdit()
        self.sensors.setPlaceholderText("accelerometer DOFs (default: the DAQ's acc:<dof> channels)")
        self.scan = QPushButton("Scan ports")
        self.scan.setToolTip("List the serial ports and ask each one *IDN?")
        self.scan.clicked.connect(self._scan)
        self.ports = QListWidget()
        self.ports.setMaximumHeight(90)

        grid.addWidget(self.use_builtin, 0, 0)
        row = QHBoxLayout()
        for w in (self.builtin_rig, self.seed, self.paced):
            row.addWidget(w)
        row.addStretch(1)
        grid.addLayout(row, 0, 1)
        grid.addWidget(self.use_file, 1, 0)
        row = QHBoxLayout()
        row.addWidget(self.rig_file, 1)
        row.addWidget(browse)
        grid.addLayout(row, 1, 1)
        grid.addWidget(self.use_real, 2, 0)
        form = QFormLayout()
        form.addRow("Shaker", self.shaker_url)
        form.addRow("DAQ", self.daq_url)
        form.addRow("Excitation DOF", self.excitation)
        form.addRow("Sensor DOFs", self.sensors)
        grid.addLayout(form, 2, 1)
        grid.addWidget(self.scan, 3, 0, Qt.AlignmentFlag.AlignTop)
        grid.addWidget(self.ports, 3, 1)

        buttons = QHBoxLayout()
        self.connect_button = QPushButton("Connect")
        self.connect_button.clicked.connect(self.connect_selected)
        self.disconnect_button = QPushButton("Disconnect")
        self.disconnect_button.clicked.connect(lambda: self.lab.act(self.lab.disconnect))
        self.connection = QLabel("not connected")
        buttons.addWidget(self.connect_button)
        buttons.addWidget(self.disconnect_button)
        buttons.addWidget(self.connection, 1)
        grid.addLayout(buttons, 4, 0, 1, 2)
        self._fill_ports()
        return box

    def _identity_box(self) -> QGroupBox:
        box = QGroupBox("Identity (*IDN?) and ranges")
        form = QFormLayout(box)
        self.shaker_idn, self.shaker_ranges = _value_label(), _value_label()
        self.protections = _value_label()
        self.protections.setTextFormat(Qt.TextFormat.RichText)
        self.protections.setToolTip("What switches the shaker output off, or ramps it, on this instrument "
                                    "(docs/protocol.md, section 9)")
        self.daq_idn, self.daq_setup = _value_label(), _value_label()
        form.addRow("Shaker controller", self.shaker_idn)
        form.addRow("Generator ranges", self.shaker_ranges)
        form.addRow("Protections", self.protections)
        form.addRow("DAQ", self.daq_idn)
        form.addRow("Acquisition", self.daq_setup)
        return box

    def _output_box(self) -> QGroupBox:
        box = QGroupBox("Output")
        form = QFormLayout(box)
        self.output_state = QLabel("OFF")
        self.output_state.setStyleSheet(OUTPUT_OFF_STYLE)
        self.output_level = _value_label()
        self.fault = _value_label()
        form.addRow("State", self.output_state)
        form.addRow("Level", self.output_level)
        form.addRow("Fault", self.fault)
        return box

    def _health_box(self) -> QGroupBox:
        box = QGroupBox("Link health (last campaign's stream)")
        form = QFormLayout(box)
        self.health = {key: _value_label() for key in ("blocks", "samples", "lost", "overloads", "faults")}
        form.addRow("Blocks received", self.health["blocks"])
        form.addRow("Samples per channel", self.health["samples"])
        form.addRow("Samples lost (gaps)", self.health["lost"])
        form.addRow("Overloaded blocks", self.health["overloads"])
        form.addRow("Faults logged", self.health["faults"])
        return box

    def _safety_box(self) -> QGroupBox:
        box = QGroupBox("Safety")
        text = QLabel("The output starts OFF and is switched on only by a Start after an explicit Arm. Abort, a "
                      "limit breach, a lost link, an instrument fault, closing this window, Ctrl+C or SIGTERM "
                      "switch it off at once; when the host falls silent or dies, the SC-1's own watchdog, or a "
                      "function generator's guardian process, switches it off (Protections, left). Every fault is "
                      "logged in the session with its time.")
        text.setWordWrap(True)
        QVBoxLayout(box).addWidget(text)
        return box

    def _arm_box(self) -> QGroupBox:
        box = QGroupBox("Limits and arming")
        form = QFormLayout(box)
        self.max_force = QDoubleSpinBox(decimals=3, minimum=1e-3, maximum=1e4, suffix=" N")
        self.max_acceleration = QDoubleSpinBox(decimals=2, minimum=1e-2, maximum=1e6, suffix=" m/s²")
        self._show_limits(*self.lab.limits)
        for spin in (self.max_force, self.max_acceleration):
            spin.setToolTip("Abort limit, checked on every block: the output goes off at once when exceeded")
            spin.valueChanged.connect(self._limits_edited)
        form.addRow("Max force", self.max_force)
        form.addRow("Max acceleration", self.max_acceleration)
        self.plan_state = _value_label()
        form.addRow("Plan", self.plan_state)
        buttons = QHBoxLayout()
        self.arm_button = QPushButton("Arm")
        self.arm_button.setToolTip("Allow the next Start to switch the output on (the plan is checked first)")
        self.arm_button.clicked.connect(lambda: self.lab.act(self.lab.arm))
        self.disarm_button = QPushButton("Disarm")
        self.disarm_button.clicked.connect(lambda: self.lab.disarm("operator"))
        buttons.addWidget(self.arm_button)
        buttons.addWidget(self.disarm_button)
        form.addRow(buttons)
        self.armed_state = _value_label()
        self.armed_state.setText("not armed")
        form.addRow("Armed", self.armed_state)
        return box

    # ------------------------------------------------------------------ actions
    def _browse_rig(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Rig file", "", "Rig files (*.toml)")
        if path:
            self.rig_file.setText(path)
            self.use_file.setChecked(True)

    def _fill_ports(self) -> None:
        ports = [device for device, _ in serial_ports()]
        for combo in (self.shaker_url, self.daq_url):
            text = combo.currentText()
            combo.clear()
            combo.addItems(ports)
            combo.setEditText(text)

    def _scan(self) -> None:
        self.ports.clear()
        self.ports.addItem("asking every listed serial port *IDN? …")
        self._fill_ports()
        self.lab.probe_ports(self._show_probes)

    def _show_probes(self, result) -> None:
        found, probes = result
        self.ports.clear()
        for p in probes:
            role = p.role or "—"
            self.ports.addItem(f"{p.url}: {role}  {p.identity or ''}  {p.detail}".strip())
        if not probes:
            self.ports.addItem("no serial ports listed; type a socket:// URL")
        if "shaker" in found:
            self.shaker_url.setEditText(found["shaker"])
        if "daq" in found:
            self.daq_url.setEditText(found["daq"])

    def connect_selected(self) -> None:
        """Connect to the instruments chosen in the panel (in the background)."""
        if self.use_real.isChecked():
            sensors = self.sensors.text().replace(",", " ").split() or None
            self.lab.act(self.lab.connect_real, self.shaker_url.currentText().strip(),
                         self.daq_url.currentText().strip(), self.excitation.text().strip(), sensors)
        else:
            rig = self.builtin_rig.currentText() if self.use_builtin.isChecked() else self.rig_file.text().strip()
            self.lab.act(self.lab.connect_simulated, rig, self.paced.isChecked(), self.seed.value())
        self.connection.setText("connecting …")

    def select_source(self, *, rig: str | None = None, shaker: str | None = None, daq: str | None = None,
                      excitation: str | None = None) -> None:
        """Preset the instrument choice (from the command line)."""
        if shaker or daq:
            self.use_real.setChecked(True)
            self.shaker_url.setEditText(shaker or "")
            self.daq_url.setEditText(daq or "")
            self.excitation.setText(excitation or "")
        elif rig in builtin_rigs():
            self.use_builtin.setChecked(True)
            self.builtin_rig.setCurrentText(rig)
        elif rig:
            self.use_file.setChecked(True)
            self.rig_file.setText(rig)

    def _limits_edited(self) -> None:
        self.lab.set_limits(self.max_force.value(), self.max_acceleration.value())

    # ------------------------------------------------------------------ views
    def _show_limits(self, max_force: float, max_acceleration: float) -> None:
        for spin, value in ((self.max_force, max_force), (self.max_acceleration, max_acceleration)):
            spin.blockSignals(True)
            spin.setValue(value)
            spin.blockSignals(False)

    def _show_busy(self, busy: bool) -> None:
        if self.lab.instruments is None:
            self.connection.setText("working …" if busy else "not connected")
        self._update_enabled()

    def _show_instruments(self) -> None:
        inst = self.lab.instruments
        if inst is None:
            self.connection.setText("not connected")
            for label in (self.shaker_idn, self.shaker_ranges, self.protections, self.daq_idn, self.daq_setup):
                label.setText("—")
        else:
            self.connection.setText(f"connected: {self.lab.connection_label}")
            s, d = inst.shaker, inst.daq
            self.shaker_idn.setText(f"{s.identity}\n{s.url}")
            self.shaker_ranges.setText(f"{s.frequency_range[0]:g}–{s.frequency_range[1]:g} Hz, "
                                       f"up to {s.amplitude_range[1]:g} V peak")
            self.protections.setText(protection_text(s.protection))
            self.daq_idn.setText(f"{d.identity}\n{d.url}")
            self.daq_setup.setText(f"{d.sample_rate:g} Hz; channels {', '.join(d.channels)}; "
                                   f"force at {inst.excitation_dof}, accelerometers at {', '.join(inst.sensor_dofs)}")
        self._update_enabled()

    def _show_status(self, status: InstrumentStatus) -> None:
        self.output_state.setText("ON" if status.output_on else "OFF")
        self.output_state.setStyleSheet(OUTPUT_ON_STYLE if status.output_on else OUTPUT_OFF_STYLE)
        level = "— (the campaign owns the instrument)" if status.level is None else f"{status.level:.4g} V"
        self.output_level.setText(level + ("  (host: armed)" if status.armed_by_host else ""))
        self.fault.setText(status.fault or "none")
        health = self.lab.link_health()
        if health is not None:
            self.health["blocks"].setText(str(health.blocks))
            self.health["samples"].setText(str(health.samples))
            self.health["lost"].setText(f"{health.lost_samples} ({health.gaps} gaps)")
            self.health["overloads"].setText(str(health.overloads))
            self.health["faults"].setText(str(health.faults))

    def _show_armed(self, armed: bool, message: str) -> None:
        self.armed_state.setText(message)
        self.armed_state.setStyleSheet(ARMED_STYLE if armed else "")
        self._update_enabled()

    def _update_enabled(self) -> None:
        running = self.lab.campaign_running
        connected = self.lab.connected
        busy = self.lab.instrument_tasks.busy and not connected
        self.connect_button.setEnabled(not running and not busy)
        self.disconnect_button.setEnabled(connected and not running)
        self.arm_button.setEnabled(connected and not running and self.lab.armed_plan is None)
        self.disarm_button.setEnabled(self.lab.armed_plan is not None)
