"""The fitters' serial maintenance console: a line-oriented command shell on a serial port.

Layers, each its own module: :mod:`~gateway.console.lines` (bytes to lines),
:mod:`~gateway.console.session` (PIN, lockout, timers, rate limit),
:mod:`~gateway.console.commands` (the command table), :mod:`~gateway.console.render`
(text for a fitter), :mod:`~gateway.console.reply` (bounded text/JSON replies),
:mod:`~gateway.console.engine` (all of these together: bytes in, bytes out),
:mod:`~gateway.console.port` (the pyserial thread with reconnect) and
:mod:`~gateway.console.view` (the seam to the service). ``docs/console.md`` is the
fitter's and integrator's guide.
"""
