"""The simulator: FlightCtrl emulator (and later URG emulator and vehicle model)."""
