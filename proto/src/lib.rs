//! Wire types shared by the coordinator, the workers and the CLI (filled by the farm issue).
