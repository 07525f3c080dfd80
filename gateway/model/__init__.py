"""The vehicle model: equations, filter coordinates."""
