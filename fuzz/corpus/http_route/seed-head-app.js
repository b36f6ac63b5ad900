HEAD /app.js
