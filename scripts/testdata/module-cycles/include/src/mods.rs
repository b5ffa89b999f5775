mod leaf;
mod m;
