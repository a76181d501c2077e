"""File > Import…: other systems' UFF58 or CSV files into a session, with the options of ``contactid import``
-- a force level, sweep direction, kind and UFF records per file, one DOF map and excitation for all
(docs/import.md)."""
from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import (QAbstractItemView, QCheckBox, QComboBox, QDialog, QDialogButtonBox, QFileDialog,
                               QFormLayout, QHBoxLayout, QHeaderView, QLabel, QLineEdit, QPlainTextEdit,
                               QPushButton, QTableWidget, QTableWidgetItem, QVBoxLayout, QWidget)

from analysis.common.errors import InputError

from ..importers.runs import SourceOptions, parse_dof_map, parse_records
from ..importers.store import ImportRequest

FROM_FILE = "from the file"
COLUMNS = ("File", "Force [N]", "Direction", "Kind", "Records")
FILE_FILTER = "Measurements (*.uff *.unv *.uff58 *.bin *.csv);;All files (*)"


class ImportDialog(QDialog):
    """Collects an :class:`~app.importers.store.ImportRequest`; :meth:`request` validates it."""

    def __init__(self, software_version: str = "", parent: QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle("Import measurements")
        self.software_version = software_version
        self.files = QTableWidget(0, len(COLUMNS))
        self.files.setHorizontalHeaderLabels(COLUMNS)
        self.files.horizontalHeader().setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        self.files.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        add, remove = QPushButton("Add files…"), QPushButton("Remove")
        add.clicked.connect(self._add_dialog)
        remove.clicked.connect(self._remove_selected)
        buttons = QHBoxLayout()
        buttons.addWidget(add)
        buttons.addWidget(remove)
        buttons.addStretch(1)
        self.dof_map = QPlainTextEdit()
        self.dof_map.setPlaceholderText("one per line: NODE[+DIR]=NAME, e.g.\n1+Z=x1\n2+Z=x2")
        self.dof_map.setMaximumHeight(90)
        self.excitation = QLineEdit()
        self.excitation.setPlaceholderText("DOF of the force where no map names it (CSV: always)")
        self.output = QLineEdit()
        browse = QPushButton("Browse…")
        browse.clicked.connect(self._output_dialog)
        out_row = QHBoxLayout()
        out_row.addWidget(self.output, 1)
        out_row.addWidget(browse)
        self.append = QCheckBox("add the runs to this existing session")
        # the command line's --force-sign -1: a file refused because its drive point gives energy out
        self.reversed_force = QCheckBox("the force's sign is reversed (--force-sign -1: every FRF changes sign)")
        form = QFormLayout()
        form.addRow("DOF map", self.dof_map)
        form.addRow("Excitation", self.excitation)
        form.addRow("", self.reversed_force)
        form.addRow("Session", out_row)
        form.addRow("", self.append)
        self.message = QLabel()
        self.message.setStyleSheet("color:#8b1a10")
        self.message.setWordWrap(True)
        box = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        box.button(QDialogButtonBox.StandardButton.Ok).setText("Import")
        box.accepted.connect(self._accept)
        box.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addWidget(QLabel("Files (UFF58 ASCII or binary, CSV long format); the file's own level and "
                                "direction are used where it states them"))
        layout.addWidget(self.files, 1)
        layout.addLayout(buttons)
        layout.addLayout(form)
        layout.addWidget(self.message)
        layout.addWidget(box)
        self.resize(820, 520)

    # -- files ----------------------------------------------------------------
    def add_files(self, paths) -> None:
        for path in paths:
            row = self.files.rowCount()
            self.files.insertRow(row)
            item = QTableWidgetItem(str(path))
            item.setToolTip(str(path))
            self.files.setItem(row, 0, item)
            self.files.setItem(row, 1, QTableWidgetItem(""))
            self.files.setCellWidget(row, 2, _combo([FROM_FILE, "up", "down"]))
            self.files.setCellWidget(row, 3, _combo([FROM_FILE, "sine", "random"]))
            records = QTableWidgetItem("")
            records.setToolTip("UFF records to import, e.g. 1,3 (one reference of a roving-hammer file); empty: all")
            self.files.setItem(row, 4, records)
        if paths and not self.output.text():
            self.output.setText(str(Path(paths[0]).with_suffix(".h5")))

    def _add_dialog(self) -> None:
        paths, _ = QFileDialog.getOpenFileNames(self, "Measurement files", "", FILE_FILTER)
        self.add_files(paths)

    def _remove_selected(self) -> None:
        for row in sorted({i.row() for i in self.files.selectedIndexes()}, reverse=True):
            self.files.removeRow(row)

    def _output_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Session to write", self.output.text(), "Sessions (*.h5)",
                                              options=QFileDialog.Option.DontConfirmOverwrite)
        if path:
            self.output.setText(path)

    # -- the request ------------------------------------------------------------
    def _row_options(self, row: int, dofs, excitation) -> SourceOptions:
        force_text = self.files.item(row, 1).text().strip()
        force = None
        if force_text:
            try:
                force = float(force_text)
            except ValueError:
                force = -1.0
            if not force > 0:
                raise InputError(f"force {force_text!r} is not a number > 0 N", self.files.item(row, 0).text(),
                                 "Force [N]")
        direction, kind = (self.files.cellWidget(row, c).currentText() for c in (2, 3))
        records = self.files.item(row, 4).text().strip()
        return SourceOptions(None if kind == FROM_FILE else kind, force,
                             None if direction == FROM_FILE else direction, dofs, excitation,
                             parse_records(records) if records else None,
                             -1.0 if self.reversed_force.isChecked() else 1.0)

    def request(self) -> ImportRequest:
        """The import as entered; InputError naming the field when something is missing or malformed."""
        if not self.files.rowCount():
            raise InputError("add at least one file to import")
        if not self.output.text().strip():
            raise InputError("choose the session file to write", field="Session")
        dofs = [parse_dof_map(line) for line in self.dof_map.toPlainText().splitlines() if line.strip()]
        excitation = self.excitation.text().strip() or None
        sources = [(self.files.item(r, 0).text(), self._row_options(r, dofs, excitation))
                   for r in range(self.files.rowCount())]
        return ImportRequest(sources, self.output.text().strip(), append=self.append.isChecked(),
                             command="gui import", software_version=self.software_version)

    def _accept(self) -> None:
        try:
            self.request()
        except InputError as exc:
            self.message.setText(str(exc))
            return
        self.accept()


def _combo(items: list[str]) -> QComboBox:
    box = QComboBox()
    box.addItems(items)
    return box
