fn main() {
    println!("million: CLI not built yet");
}
