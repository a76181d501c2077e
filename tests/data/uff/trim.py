"""Cut the long time histories of pyuff's sample files to their first points, keeping every record whole.

    python tests/data/uff/trim.py SOURCE.uff TARGET.uff [POINTS]

A dataset 58 (text) or 58b (binary) record keeps its header lines as they were, with the number of points in
record 7 (and, for 58b, the byte count on its '58b' line) set to the points kept; the data keep their first
POINTS values (default 4096) and the bytes between the data and the next record stay as they were, so a broken
layout of the source (a 58b whose closing '-1' stands on a line of its own) is kept too. Records other than 58
are copied unchanged. The shipped files were made with it from the files of pyuff's data/ folder.
"""
import re
import sys


def _line_end(data: bytes, at: int) -> int:
    """Index just past the end of the line starting at ``at``."""
    end = data.index(b"\n", at)
    return end + 1


def trim(data: bytes, points: int) -> bytes:
    out = bytearray()
    at = 0
    while True:
        match = re.compile(rb"^ *-1\r?\n *(58b?)(?=[ \r\n])", re.M).search(data, at)
        if match is None:
            out += data[at:]
            return bytes(out)
        out += data[at:match.start(1)]
        head_end = _line_end(data, match.start(1))
        head = data[match.start(1):head_end]
        header = []
        cursor = head_end
        for _ in range(11):
            nxt = _line_end(data, cursor)
            header.append(data[cursor:nxt])
            cursor = nxt
        fields = header[6].split()
        total = int(fields[1])
        keep = min(points, total)
        header[6] = header[6].replace(fields[1], str(keep).encode().rjust(len(fields[1])), 1)
        if head.startswith(b"58b"):
            parts = head.split()
            nbytes = int(parts[4])
            width = nbytes // total
            head = head.replace(parts[4], str(keep * width).encode().rjust(len(parts[4])), 1)
            body = data[cursor:cursor + keep * width]
            after = cursor + nbytes
        else:
            end = re.compile(rb"^ *-1\r?$", re.M).search(data, cursor).start()
            values_per_line = len(data[cursor:_line_end(data, cursor)].split())
            lines, rest = divmod(keep, values_per_line)
            stop = cursor
            for _ in range(lines):
                stop = _line_end(data, stop)
            body = data[cursor:stop]
            if rest:
                row = data[stop:_line_end(data, stop)]
                newline = b"\r\n" if row.endswith(b"\r\n") else b"\n"
                width = len(row.rstrip(b"\r\n")) // values_per_line
                body += row[:rest * width] + newline
            after = end
        out += head + b"".join(header) + body
        at = after


if __name__ == "__main__":
    source, target = sys.argv[1], sys.argv[2]
    count = int(sys.argv[3]) if len(sys.argv) > 3 else 4096
    with open(source, "rb") as f:
        raw = f.read()
    with open(target, "xb") as f:
        f.write(trim(raw, count))
