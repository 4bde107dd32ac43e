"""Pictures of a memory for people: contact sheets of hits (`sheet`) and rerun recordings of the
trajectory, keyframes and query hits (`rerun`). A top floor, like `cli`: it may use memory, tools
and agent; only the CLI and the service import it."""
