"""The long-running memory a robot holds, below every transport.

One process holds one memory for a live robot; HTTP and the page and MCP (`ravenmem.server`),
ROS 2 and Zenoh (`ravenmem.ros`) and the CLI's remote mode are front ends over what lives here,
and none of it knows about a wire format:

- `service`: the served memory (`Service`): searches through `ravenmem.tools`, questions through
  the one `agent.ask`, the one goal path, results in the one JSON shape with images as URLs;
- `live`: `LiveWriter`, the one writer: frame + pose + time -> the admission stage -> store,
  answering with the new id or the reason the frame was skipped;
- `events`: the event stream every front end may listen to (memories, skips, answers);
- `images`: decoding uploaded pictures and depth under a RAM budget.
"""
