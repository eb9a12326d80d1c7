"""The MCP tool layer: thin tool functions that translate MCP ⇄ Guard, plus transports."""
