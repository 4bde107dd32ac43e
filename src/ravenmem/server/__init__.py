"""`ravenmem serve`: one long-running process that holds a memory for a live robot.

Rooms, each a thin layer over memory + tools + agent (no search logic of their own):

- `service`: the served memory (`Service`): searches through `ravenmem.tools`, questions through
  the agent's methods, results in the one JSON shape with images as URLs;
- `live`: `LiveWriter`, the one writer: frame + pose + time -> keyframe rule -> embedder -> store,
  answering with the new id or the reason the frame was skipped (the HTTP route and the robot
  link both use it);
- `app`: the HTTP API (FastAPI), routes generated from the tools table, the page, `/mcp`;
- `security`: loopback without a token, any other address only with one;
- `mcp_tools`: the tools as MCP tools (stdio and streamable HTTP);
- `client`: the HTTP client behind `ravenmem search/ask/info --server URL`;
- `run`: start it (`ravenmem serve`);
The robot link (ROS 2 topics over Zenoh into the memory, goals and `ravenmem_msgs` services
back) lives a floor up, in `ravenmem.ros`, and attaches itself to a `Service`.

Importing this package imports none of the web stack; `client` needs only httpx.
"""
