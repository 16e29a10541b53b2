"""Hardware layer: serial protocol, links, device drivers, emulator and acquisition.

Modules (one job each)::

    nmea         sentence encode / checksum / robust byte-stream parser
    errors       typed errors: LinkLost, ReplyTimeout, DeviceError, GaveUp
    linkio       one serial port by pyserial URL: framing, raw log, reopen with back-off
    drivers      SensorDriver, PlatformDriver (reader thread, replies matched by type + key)
    faults       fault-injection plan of the emulator (``--faults`` text)
    endpoints    where the emulator's bytes go: pseudo-terminals or in-process pipes
    anglesensors the emulated platform's X and Y angle sensors and their errors
    emulator     both devices on one device clock (physics from chekan.records.simulate)
    protocol_chekanemu   pyserial URL scheme ``chekanemu://sensor?session=NAME``
    journal      fsynced JSON-lines journal of a run
    acquisition  the runner, a package: plan, summary, clock (seq → t_s), steps (the
                 step machine), links (reconnects), recorder (record, journal, raw
                 log), runner, start (acquire), resume
    cli          ``chekan emulate`` / ``chekan acquire`` sub-commands

Protocol contract: ``docs/specs/serial-protocol.md``.
"""

import serial as _serial

if "hw" not in _serial.protocol_handler_packages:  # chekanemu:// (hw/protocol_chekanemu.py)
    _serial.protocol_handler_packages.append("hw")
