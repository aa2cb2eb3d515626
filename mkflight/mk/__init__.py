"""The MikroKopter FlightCtrl: frames, messages, raw<->SI units and the async link."""
