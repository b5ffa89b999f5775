mod q;
pub struct Pee;
pub fn run() {
    q::go();
}
