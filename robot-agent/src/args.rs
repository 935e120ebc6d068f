//! Every option of the robot-agent process (`robot-agent --help`): the process contract's
//! [`contract::AgentArgs`], so the launcher and this process read the same struct.

pub use contract::AgentArgs;
