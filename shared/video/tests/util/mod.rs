pub mod perceive;
