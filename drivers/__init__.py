"""Drive protocol codecs, host-side drive classes, transports and safety limits."""
