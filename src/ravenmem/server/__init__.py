"""`ravenmem serve`: one long-running process that holds a memory for a live robot.

Rooms, each a thin front end over the application core (`ravenmem.runtime`: the served
memory, its live writer, events and picture decoding), with no search logic of their own:

- `app`: the HTTP API (FastAPI), routes generated from the tools table, the page, `/mcp`;
- `security`: loopback without a token, any other address only with one;
- `mcp_tools`: the tools as MCP tools (stdio and streamable HTTP);
- `client`: the HTTP client behind `ravenmem search/ask/info --server URL`;
- `run`: start it (`ravenmem serve`);
The robot link (ROS 2 topics over Zenoh into the memory, goals and `ravenmem_msgs` services
back) is a sibling front end, `ravenmem.ros`, over the same `runtime.Service`.

Importing this package imports none of the web stack; `client` needs only httpx.
"""
