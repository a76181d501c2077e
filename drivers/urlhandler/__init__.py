"""pyserial URL handlers of contactid (registered in ``serial.protocol_handler_packages``)."""
