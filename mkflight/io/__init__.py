"""The one place that opens serial ports and pseudo-terminals (the ByteStream seam)."""
