"""dvfc: passivity-based dynamic visual feedback control, executable and checkable."""
